"""docs/design.md is the map from the paper to the code: every function it names exists.

The equation index is only useful while it is true, so this test reads each backquoted
dotted name of the form ``bubblefit.x.y`` in the design notes and imports it.
"""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "design.md"
NAMES = sorted(set(re.findall(r"`(bubblefit(?:\.\w+)+)`", DOC.read_text())))


def _resolve(dotted: str):
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:k]))
        except ModuleNotFoundError:
            continue
        for attr in parts[k:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


def test_the_index_names_functions():
    assert len(NAMES) >= 15, "the equation index lost its entries"


@pytest.mark.parametrize("dotted", NAMES)
def test_every_named_function_exists(dotted):
    assert _resolve(dotted) is not None


def test_every_equation_of_the_paper_is_indexed():
    text = DOC.read_text()
    index = text[text.index("## Equation index"):]
    covered = {int(n) for n in re.findall(r"\beq\. \((\d+)\)", index)}
    for lo, hi in re.findall(r"\beqs\. \((\d+)\)-\((\d+)\)", index):
        covered |= set(range(int(lo), int(hi) + 1))
    assert set(range(1, 15)) <= covered, sorted(set(range(1, 15)) - covered)
