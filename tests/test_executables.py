"""The store of compiled executables (bubblefit.io.executables): a new process loads the
program instead of tracing it, gets the same numbers, and never runs a stale program.

Each case runs in fresh processes that share one cache folder, as commands do. The
program has the parts the fit's solve has that XLA:CPU must restore: a while loop, a
LAPACK call (QR) and fusions; the third process loads an executable that was stored
after the persistent compilation cache already held the same program (the case where
re-serialising the cache's copy lost its kernels)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

SCRIPT = textwrap.dedent("""
    import sys, json
    from bubblefit.io.jaxcache import jax_setup
    jax_setup(sys.argv[1])
    import jax, jax.numpy as jnp, jax.monitoring
    from bubblefit.io import executables

    compiles = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, secs, **kw: compiles.append(event) if event.endswith("backend_compile_duration") else None)

    scale = float(sys.argv[2])

    def f(a, b):
        print("traced", file=sys.stderr)
        q, r = jnp.linalg.qr(a)
        out = jax.lax.while_loop(lambda c: c[1] < 4, lambda c: (jnp.tanh(c[0] @ r) * scale, c[1] + 1), (b, 0))[0]
        return {"x": out, "s": jnp.sum(q)}

    fn = jax.jit(f)
    if sys.argv[3] in ("store", "prepare"):
        fn = executables.stored(fn, "test.f", (scale,))
    if sys.argv[3] == "deferred":  # the jitted function built only where it is called or lowered
        fn = executables.stored(executables.deferred(lambda: print("built", file=sys.stderr) or jax.jit(f)),
                                "test.f", (scale,))
    a = jnp.arange(16.0).reshape(4, 4) / 10 + jnp.eye(4)
    if sys.argv[3] == "prepare":  # compiled in the background, then called
        fn.prepare(a, jnp.zeros((4, 4)))
        print(f"pending {len(fn.pending)}", file=sys.stderr)
    res = fn(a, jnp.ones((4, 4)))
    print(json.dumps({k: jnp.asarray(v).tolist() for k, v in res.items()}))
    print(f"compiled {len(compiles)}", file=sys.stderr)
    if sys.argv[3] == "prepare":
        print(f"waiting {len(fn.pending)}", file=sys.stderr)
""")


_LAST_STDERR = [""]


def _run(cache, scale, how):
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(cache), str(scale), how], capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    _LAST_STDERR[:] = [out.stderr]
    import json

    compiled = int(out.stderr.rsplit("compiled ", 1)[1].split()[0])
    return json.loads(out.stdout.strip().splitlines()[-1]), out.stderr.count("traced"), compiled


def test_a_new_process_loads_the_program_and_gets_the_same_numbers(tmp_path):
    cache = tmp_path / "cache"
    plain, traced, _ = _run(cache, 0.5, "plain")  # fills the persistent compilation cache
    assert traced == 1
    first, traced, _ = _run(cache, 0.5, "store")  # compiles afresh and stores the executable
    assert traced == 1 and len(list((cache / "executables").glob("*.bin"))) == 1
    # stored without the traced operations' names (HLO metadata), which a load would parse
    assert b"jit(f)/" not in next((cache / "executables").glob("*.bin")).read_bytes()
    second, traced, _ = _run(cache, 0.5, "deferred")  # loads it: no tracing, and a deferred function never built
    assert traced == 0 and "built" not in _LAST_STDERR[0]
    for res in (first, second):
        np.testing.assert_array_equal(res["x"], plain["x"])
        np.testing.assert_array_equal(res["s"], plain["s"])


def test_a_prepared_program_is_compiled_once_in_the_background(tmp_path):
    """``prepare`` compiles (and stores) the program in the background thread; the call
    with arguments of the same shapes runs it: traced once, the same numbers, one file. In
    a new process ``prepare`` leaves the stored program to the call, which loads it."""
    cache = tmp_path / "cache"
    plain, _, _ = _run(tmp_path / "plain", 0.5, "plain")
    _, _, compiled = _run(tmp_path / "store", 0.5, "store")
    first, traced, compiled_prepared = _run(cache, 0.5, "prepare")
    assert traced == 1 and len(list((cache / "executables").glob("*.bin"))) == 1
    # the call took the background's program: none left waiting, none compiled twice
    assert _LAST_STDERR[0].count("waiting 0") == 1 and compiled_prepared == compiled
    assert _LAST_STDERR[0].count("pending 1") == 1  # under way in the background
    second, traced, _ = _run(cache, 0.5, "prepare")  # a new process: loaded from the store by the call
    assert traced == 0 and _LAST_STDERR[0].count("pending 0") == 1  # nothing loaded ahead
    for res in (first, second):
        np.testing.assert_array_equal(res["x"], plain["x"])
        np.testing.assert_array_equal(res["s"], plain["s"])


def test_the_persistent_cache_is_bypassed_in_one_thread_only(monkeypatch):
    """A background compile bypasses JAX's persistent cache (its executable must be fresh
    to serialise whole); the other threads' compiles still use it."""
    import threading

    from jax._src import compilation_cache

    from bubblefit.io import executables

    monkeypatch.setattr(compilation_cache, "is_cache_used", lambda backend: True)
    seen, inside, checked = {}, threading.Event(), threading.Event()

    def worker():
        with executables._persistent_cache(False):
            seen["worker"] = compilation_cache.is_cache_used(None)
            inside.set()
            checked.wait(30)
        seen["worker after"] = compilation_cache.is_cache_used(None)

    thread = threading.Thread(target=worker)
    thread.start()
    assert inside.wait(30)
    seen["main"] = compilation_cache.is_cache_used(None)
    checked.set()
    thread.join(30)
    assert seen == {"worker": False, "main": True, "worker after": True}


def test_a_changed_setting_is_a_new_program(tmp_path):
    cache = tmp_path / "cache"
    a, _, _ = _run(cache, 0.5, "store")
    b, traced, _ = _run(cache, 0.25, "store")
    assert traced == 1 and len(list((cache / "executables").glob("*.bin"))) == 2
    assert not np.allclose(a["x"], b["x"])


def test_a_damaged_file_falls_back_to_compiling(tmp_path):
    cache = tmp_path / "cache"
    good, _, _ = _run(cache, 0.5, "store")
    for path in (cache / "executables").glob("*.bin"):
        path.write_bytes(b"not an executable")
    again, traced, _ = _run(cache, 0.5, "store")
    assert traced == 1
    np.testing.assert_array_equal(again["x"], good["x"])


def test_a_program_that_fails_its_first_run_is_dropped(tmp_path, monkeypatch):
    """A stored program that loads but fails when run (a kernel it cannot find) is deleted,
    and the call is answered by the plain jitted function."""
    import jax
    import jax.numpy as jnp

    from bubblefit.io import executables

    def broken(*args):
        raise RuntimeError("NOT_FOUND: Function fusion not found")

    fn = jax.jit(lambda x: jnp.sin(x) * 2)
    x = jnp.linspace(0.0, 1.0, 5)
    monkeypatch.setattr(executables, "ENABLED", True)
    monkeypatch.setattr(executables, "_folder", lambda: tmp_path)
    monkeypatch.setattr(executables, "_load", lambda path, args: broken)
    key = executables._key("test.broken", executables._static_bytes(()), (x,))
    (tmp_path / f"{key}.bin").write_bytes(b"stale")
    call = executables.stored(fn, "test.broken", ())
    np.testing.assert_array_equal(call(x), fn(x))
    assert not (tmp_path / f"{key}.bin").exists()
    np.testing.assert_array_equal(call(x), fn(x))  # and it stays on the jitted path


def test_a_library_call_takes_the_program_prepared_in_the_background(monkeypatch):
    """Without the store (library calls), ``prepare`` compiles in the background all the
    same, not saved; the call with the same shapes runs that program (none left
    waiting) and gets the jitted function's numbers; other shapes take the jitted path."""
    import jax
    import jax.numpy as jnp

    from bubblefit.io import executables

    monkeypatch.setattr(executables, "ENABLED", False)
    fn = jax.jit(lambda x: jnp.cumsum(jnp.sin(x) * 3.0))
    call = executables.stored(fn, "test.library", ())
    x = jnp.linspace(0.0, 2.0, 7)
    call.prepare(jnp.zeros_like(x))
    np.testing.assert_array_equal(call(x), fn(x))
    assert not call.pending and len(call.loaded) == 1
    y = jnp.linspace(0.0, 1.0, 5)  # not prepared: the plain jitted call
    np.testing.assert_array_equal(call(y), fn(y))
    assert len(call.loaded) == 1


def _in_process_store(monkeypatch, tmp_path):
    """The store turned on in this process, with its folder in ``tmp_path`` (created private)."""
    from bubblefit.io import executables
    from bubblefit.io.jaxcache import private_folder

    folder = tmp_path / "cache" / "executables"
    assert private_folder(folder) is None
    monkeypatch.setattr(executables, "ENABLED", True)
    monkeypatch.setattr(executables, "_folder", lambda: folder)
    return executables, folder


def test_a_planted_file_is_never_run(tmp_path, monkeypatch):
    """A file planted under the name the store will look up (a pickle whose loading would
    create a marker file, as the store's earlier format would have run) is ignored and
    replaced by the store's own file; the call gets the jitted function's numbers."""
    import os
    import pickle

    import jax
    import jax.numpy as jnp

    executables, folder = _in_process_store(monkeypatch, tmp_path)
    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    fn = jax.jit(lambda x: jnp.cos(x) * 3.0)
    x = jnp.linspace(0.0, 1.0, 6)
    key = executables._key("test.planted", executables._static_bytes(()), (x,))
    planted = folder / f"{key}.bin"
    planted.write_bytes(pickle.dumps(Payload()))
    call = executables.stored(fn, "test.planted", ())
    np.testing.assert_array_equal(call(x), fn(x))
    assert not marker.exists()
    assert planted.read_bytes().startswith(executables.MAGIC)  # replaced by the store's own file


_DIGEST_SCRIPT = r"""
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from bubblefit.io import executables
from bubblefit.io.jaxcache import private_folder

folder = Path(sys.argv[1]) / "cache" / "executables"
assert private_folder(folder) is None
executables.ENABLED = True
executables._folder = lambda: folder
loads, load = [], executables._load


def recording_load(path, args):
    try:
        out = load(path, args)
    except Exception as exc:
        loads.append(type(exc).__name__)
        raise
    loads.append("loaded")
    return out


executables._load = recording_load
fn = jax.jit(lambda x: ({"y": jnp.sin(x) + 1.0, "n": None}, jnp.sum(x)))
x = jnp.linspace(0.0, 2.0, 9)
want = fn(x)
got = executables.stored(fn, "test.digest", ())(x)  # compiled afresh and saved
np.testing.assert_array_equal(got[0]["y"], want[0]["y"])
path = next(folder.glob("*.bin"))
good = path.read_bytes()
assert good.startswith(executables.MAGIC)

loads.clear()
loaded = executables.stored(fn, "test.digest", ())(x)  # a new Stored: read from the file
assert loads == ["loaded"] and loaded[0]["n"] is None and path.exists(), loads
np.testing.assert_array_equal(loaded[0]["y"], want[0]["y"])
np.testing.assert_array_equal(loaded[1], want[1])

(folder / ".key").write_bytes(b"k" * executables.SECRET_BYTES)  # another store's key
loads.clear()
np.testing.assert_array_equal(executables.stored(fn, "test.digest", ())(x)[1], want[1])
assert loads == ["StoreError"] and path.read_bytes() != good, loads  # rewritten under this key
for cut in (0, len(good) // 2):
    path.write_bytes(path.read_bytes()[:cut])
    loads.clear()
    np.testing.assert_array_equal(executables.stored(fn, "test.digest", ())(x)[1], want[1])
    assert loads == ["StoreError"] and path.stat().st_size > len(good) // 2, (cut, loads)
print("ok")
"""


def test_a_file_without_the_stores_digest_is_ignored(tmp_path):
    """A file in the store's format whose digest was made with another key (copied from
    another cache, or forged) or that is cut short is not loaded: the program is compiled
    and the file replaced; a file the store wrote is loaded in a later call.

    Run in two processes of their own that share JAX's persistent compilation cache, as
    commands do: in the second, the plain call of the function loads it from that cache,
    and the store must still save a program compiled afresh (one loaded from the
    persistent cache lacks its fused kernels; saved, it failed its first run after loading
    and was deleted, so the refusals below were never reached). The environment is set
    here, not inherited from whatever the test process holds."""
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax"),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0", "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "0",
           "JAX_ENABLE_X64": "0"}
    for run in ("first", "second"):  # the second finds the function in JAX's cache
        out = subprocess.run([sys.executable, "-c", _DIGEST_SCRIPT, str(tmp_path / run)], capture_output=True,
                             text=True, timeout=300, env=env)
        assert out.returncode == 0 and out.stdout.strip().endswith("ok"), (run, out.stderr[-2000:])
    assert any((tmp_path / "jax").glob("*-cache")), "JAX's persistent cache was not used"


def test_a_cache_folder_others_can_write_is_not_used(tmp_path):
    """The cache folder is created ``0700``; one that the group or others can write is
    refused in one line, and neither JAX's cache nor the store uses it."""
    import os
    import stat

    from bubblefit.io.jaxcache import private_folder

    new = tmp_path / "new" / "cache"
    assert private_folder(new) is None and stat.S_IMODE(new.stat().st_mode) == 0o700
    shared = tmp_path / "shared"
    shared.mkdir()
    os.chmod(shared, 0o777)
    assert "writable by others" in private_folder(shared)
    script = ("import os, jax; from bubblefit.io.jaxcache import jax_setup; from bubblefit.io import executables; "
              "s = jax_setup(os.environ['C']); "
              "print(s['cache_dir'], jax.config.jax_compilation_cache_dir, executables._folder())")
    out = subprocess.run([sys.executable, "-c", script], env={**os.environ, "C": str(shared),
                                                             "BUBBLEFIT_CACHE_DIR": str(shared)},
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.split() == ["None", "None", "None"]
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "not using the compilation cache" in lines[0] and str(shared) in lines[0]


def test_unreadable_jax_cache_entries_are_replaced_and_write_errors_said_once(tmp_path, monkeypatch, capsys):
    """An entry of JAX's cache cut short (a full disk) is deleted when it fails to load, so
    the compile that follows writes it anew; failed writes are one warning line in all."""
    from jax._src import compilation_cache

    from bubblefit.io import executables, jaxcache

    monkeypatch.setattr(jaxcache, "_WARNED", set())
    calls = []

    def failing_get(key, *args, **kwargs):
        calls.append(key)
        raise ValueError("truncated entry")

    def failing_put(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(compilation_cache, "get_executable_and_time", failing_get)
    monkeypatch.setattr(compilation_cache, "put_executable_and_time", failing_put)
    monkeypatch.setattr(executables, "_jax_cache_dir", lambda: str(tmp_path))
    executables._guard_jax_cache()
    entry = tmp_path / "jit_f-abc-cache"
    entry.write_bytes(b"cut")
    assert compilation_cache.get_executable_and_time("jit_f-abc") == (None, None)
    assert calls == ["jit_f-abc"] and not entry.exists()
    for _ in range(3):
        compilation_cache.put_executable_and_time("k", "m", None, None, 0)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no space left on device" in err[0]


def _version(parts) -> str:
    return ".".join(str(p) for p in parts)


def test_the_ynn_option_is_given_only_for_a_known_jaxlib_and_never_over_the_users_flag(monkeypatch):
    """The solves' option that turns XLA:CPU's YNNPACK fusions off is given for the jaxlib
    versions in the known range only (an experimental option another jaxlib may lack), and
    not when the user's ``XLA_FLAGS`` sets the flag (their choice holds for every program)."""
    from bubblefit.io import jaxcache

    first, last = jaxcache.YNN_FLAG_JAXLIB
    outside = [_version(last[:-1] + (last[-1] + 1,)), _version((last[0] + 1,) + last[1:]),
               _version(last) + ".dev20260101", "not-a-version"]
    if first[-1] > 0:
        outside.append(_version(first[:-1] + (first[-1] - 1,)))
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")
    for version in outside:
        assert jaxcache.ynn_fusions_off_option(version) == ()
    for version in (first, last):
        assert jaxcache.ynn_fusions_off_option(_version(version)) == (("xla_cpu_experimental_ynn_fusion_type", ""),)
    monkeypatch.setenv("XLA_FLAGS", f"{jaxcache.YNN_FLAG}=reduce")
    assert jaxcache.ynn_fusions_off_option(_version(first)) == ()
    assert os.environ["XLA_FLAGS"] == f"{jaxcache.YNN_FLAG}=reduce"  # nothing is written
    assert jaxcache.ynn_fusion_setting(f"{jaxcache.YNN_FLAG}=a {jaxcache.YNN_FLAG}=") == ""
    assert jaxcache.ynn_fusion_setting("--xla_other=1") is None


def test_the_fusion_setting_is_part_of_the_stores_key(monkeypatch):
    """A program compiled with XLA:CPU's YNNPACK fusions is never loaded as one without."""
    from bubblefit.io import executables
    from bubblefit.io.jaxcache import YNN_FLAG

    keys = set()
    for flags in (None, f"{YNN_FLAG}=", f"{YNN_FLAG}=reduce"):
        if flags is None:
            monkeypatch.delenv("XLA_FLAGS", raising=False)
        else:
            monkeypatch.setenv("XLA_FLAGS", flags)
        keys.add(executables._key("f", b"", (np.ones(2, np.float32),)))
    assert len(keys) == 3


def test_the_installed_jaxlib_takes_the_solves_option():
    """With the installed jaxlib a known one, a row reduction that XLA:CPU hands to YNNPACK
    by default hands it nothing when compiled with the solves' options
    (:data:`bubblefit.inverse._programs.FINAL_COMPILE`), and both compute it exactly."""
    import jax
    import jax.numpy as jnp

    from bubblefit.inverse._programs import FINAL_COMPILE
    from bubblefit.io import jaxcache

    option = jaxcache.ynn_fusions_off_option()
    if not option:
        pytest.skip("the installed jaxlib is not one the option is known for")
    assert set(option) <= set(FINAL_COMPILE)
    x = jnp.tile(jnp.arange(8.0), (512, 8))  # (512, 64): a row reduction XLA:CPU hands to YNNPACK by default

    def rows(v):
        return jnp.sum(v * v, axis=1)

    default = jax.jit(rows).lower(x).compile()
    compiled = jax.jit(rows, compiler_options=dict(FINAL_COMPILE)).lower(x).compile()
    assert "ynn" in default.as_text().lower() and "ynn" not in compiled.as_text().lower()
    expected = 8.0 * sum(i * i for i in range(8))  # integers: exact in float32
    assert np.all(np.asarray(compiled(x)) == expected) and np.all(np.asarray(default(x)) == expected)


def test_the_jaxlib_version_is_read_without_importing_it(monkeypatch):
    """The version read from the installed wheel's folder is the one its metadata gives."""
    from importlib import metadata

    from bubblefit.io import jaxcache

    monkeypatch.delitem(sys.modules, "jaxlib")  # as before JAX is imported
    assert jaxcache._jaxlib_version() == metadata.version("jaxlib")


def test_pruning_skips_files_another_process_removed(tmp_path, monkeypatch):
    """Two processes sharing the store prune it at once: a file listed by one and removed by
    the other before it is read must not stop the pruning (nor be reported as a failed write),
    and the oldest files still present go first until the folder fits its limit."""
    from pathlib import Path

    from bubblefit.io import executables

    sizes = [100, 100, 100]
    paths = []
    for k, size in enumerate(sizes):
        p = tmp_path / f"p{k}.bin"
        p.write_bytes(b"x" * size)
        os.utime(p, (1000.0 + k, 1000.0 + k))  # p0 is the least recently used
        paths.append(p)
    gone = tmp_path / "gone.bin"  # listed, but removed before it is read
    listing = Path.glob

    def glob_with_a_vanished_file(self, pattern):
        return [gone] + list(listing(self, pattern))

    monkeypatch.setattr(Path, "glob", glob_with_a_vanished_file)
    executables._prune(tmp_path, limit_bytes=150)
    assert [p.exists() for p in paths] == [False, False, True]
