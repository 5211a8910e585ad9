"""The documentation's examples run, and what they print is what they say.

Two sources of examples:

- every fenced ``python`` block of ``README.md`` and ``docs/**/*.md``, executed as a
  script in a fresh namespace inside an empty temporary folder (a block preceded by
  ``<!-- docs-test: slow -->`` runs an end-to-end fit and is marked slow; one preceded by
  ``<!-- docs-test: skip (why) -->`` needs files a user brings and is only compiled);
- the ``>>>`` examples of the public API's docstrings (``bubblefit.__all__`` and the
  methods of its classes), run by :mod:`doctest`; those that compile a fit or a render
  are marked slow.

The examples carry their own checks (``assert`` lines, printed values doctest compares).
"""

from __future__ import annotations

import doctest
import importlib
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCE = re.compile(r"(?:<!--\s*docs-test:\s*(?P<mark>slow|skip)[^>]*-->\s*\n)?^```python\n(?P<code>.*?)^```",
                   re.S | re.M)
# Docstring examples that compile a fit or a render (tens of seconds on a first call).
SLOW_DOCTESTS = {"render_scene", "fit_photo", "calibrate", "fit_spectrum"}
# Public functions whose docstrings must keep a runnable example (the entry points users
# meet first); the test fails if one loses it.
MUST_HAVE_EXAMPLES = {"read_image", "write_image", "render_scene", "fit_photo", "calibrate",
                      "fit_spectrum", "interference_colours", "spectral_basis", "EnvMap.from_array",
                      "read_spectrum", "load_scene", "Params.make"}


def _blocks():
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for m in FENCE.finditer(text):
            line = text.count("\n", 0, m.start("code")) + 1
            name = f"{page.relative_to(ROOT)}:{line}"
            marks = [pytest.mark.slow] if m.group("mark") == "slow" else []
            yield pytest.param(name, m.group("code"), m.group("mark"), id=name, marks=marks)


def _docstring_tests():
    import bubblefit

    finder = doctest.DocTestFinder(recurse=False)
    seen = set()
    for public in bubblefit.__all__:
        obj = getattr(bubblefit, public)
        members = [(public, obj)]
        if inspect.isclass(obj):
            members += [(f"{public}.{k}", v) for k, v in vars(obj).items() if not k.startswith("_")]
        for name, member in members:
            target = member.__func__ if isinstance(member, (staticmethod, classmethod)) else member
            if id(target) in seen or not (inspect.isfunction(target) or inspect.isclass(target)):
                continue
            seen.add(id(target))
            module = importlib.import_module(target.__module__)
            for test in finder.find(target, name, module=module, globs={}):
                if test.examples:
                    yield name, test


DOCTESTS = dict(_docstring_tests())


@pytest.mark.parametrize("name,code,mark", list(_blocks()))
def test_markdown_example(name, code, mark, tmp_path, monkeypatch):
    compiled = compile(code, name, "exec")
    if mark == "skip":
        return  # needs the user's own files: compiling it is all that can be checked
    monkeypatch.chdir(tmp_path)
    exec(compiled, {"__name__": "__docs__"})


def test_pages_have_examples():
    """The scan finds the examples (a change of fence syntax would silently drop them)."""
    blocks = list(_blocks())
    assert any(p.values[0].startswith("README.md") for p in blocks)
    assert sum(1 for p in blocks if p.values[0].startswith("docs")) >= 3


def test_public_functions_keep_their_examples():
    missing = MUST_HAVE_EXAMPLES - set(DOCTESTS)
    assert not missing, f"docstring examples missing for {sorted(missing)}"


@pytest.mark.parametrize("name", [pytest.param(n, marks=[pytest.mark.slow] if n in SLOW_DOCTESTS else [])
                                  for n in sorted(DOCTESTS)])
def test_docstring_example(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    test = DOCTESTS[name]
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    out = []
    runner.run(test, out=out.append)
    assert runner.failures == 0, "".join(out)


def test_readme_is_a_front_page():
    """The README stays short and its relative links point at files that exist."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 160
    for target in re.findall(r"\]\((?!https?://|#)([^)#\s]+)", text):
        assert (ROOT / target).exists(), f"README links {target}, which does not exist"
