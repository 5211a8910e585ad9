"""Compiled programs kept on disk, so that a new process does not trace them again.

JAX's persistent compilation cache (:mod:`bubblefit.io.jaxcache`) saves XLA's compile,
but its key is the lowered program: every process still traces the Python function to a
jaxpr and lowers it to MLIR before it can look the program up. For the fit's
Levenberg-Marquardt solve (the render, its Jacobian, the trust region and the QR inside
one ``while_loop``) that is about 0.5 s of tracing and 0.3 s of lowering per program,
every process. :func:`stored` keeps the compiled executable itself
(:mod:`jax.experimental.serialize_executable`) under a key computed without tracing:

- what the function is: a name and the static values it closes over (the render
  configuration, the parameter table, the solver's settings), pickled;
- the code it runs: a digest of every ``.py`` file of the bubblefit package, and the
  versions of JAX and jaxlib, the backend and the float64 flag;
- what it is called with: the arguments' tree structure, shapes and dtypes.

A change to any of them is a new key, so a stale program is never run. Any failure to
store, to load or to run a loaded program the first time (a program with closed-over
constants, a read-only cache, a damaged file) falls back to the plain jitted call. Files live in ``executables/`` of the
compilation cache's folder (at most :data:`MAX_BYTES`). The store is used in processes
that called :func:`~bubblefit.io.jaxcache.jax_setup` (the command line and its workers).

A program needed later can be started ahead (:meth:`Stored.prepare`): it is loaded or
compiled in a background thread (:data:`COMPILE_THREADS` of them) while the caller goes
on, and the call with arguments of the same shapes waits for it (the fit prepares its
final solve, its final render and its standard errors' programs before the global search).

Two things XLA:CPU needs, found by running it: an executable is serialised from a fresh
compile (one that the persistent cache loaded loses its fused kernels), and the LAPACK
kernels are initialised before a loaded program runs (JAX does it while lowering, which a
loaded program skips).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import hashlib
import pickle
import threading
from pathlib import Path
from typing import Any, Callable

__all__ = ["Stored", "stored", "source_digest"]

#: Folder, under the compilation cache's, that holds the stored executables.
FOLDER = "executables"
#: Most bytes the folder keeps (a fit's solve is 2-3 MB); the least recently used go first.
MAX_BYTES = 512 * 2**20
#: Background threads that :meth:`Stored.prepare` compiles in. Two: a fit prepares its final
#: solve and its final render, and with one thread the render's compile queued behind the
#: solve's, the longest on an empty cache's first fit, while the fit itself waited.
COMPILE_THREADS = 2
#: Whether :func:`stored` uses the store: set by :func:`bubblefit.io.jaxcache.jax_setup`
#: (the command line, the sequence workers); library calls without it jit as usual.
ENABLED = False
_LOCK = threading.Lock()
#: Per-thread state: whether this thread's compiles bypass the persistent cache.
_THREAD = threading.local()


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 of every ``.py`` file of the bubblefit package (names and contents)."""
    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _folder() -> Path | None:
    import jax

    from .jaxcache import jax_settings

    cache = getattr(jax.config, "jax_compilation_cache_dir", None) or jax_settings()["cache_dir"]
    return Path(cache) / FOLDER if cache else None


def _static_bytes(static: Any) -> bytes | None:
    """``static`` pickled, or None when it cannot be (no stored program, only the jitted one)."""
    try:
        return pickle.dumps(static, protocol=4)
    except Exception:
        return None


def _key(name: str, static_bytes: bytes, args: tuple) -> str:
    """The executable's key (hex digest) for arguments ``args``."""
    import jax
    import jaxlib

    leaves, tree = jax.tree_util.tree_flatten(args)
    h = hashlib.sha256()
    for part in (name, source_digest(), jax.__version__, jaxlib.__version__, jax.default_backend(),
                 str(jax.devices()[0].device_kind), str(bool(jax.config.jax_enable_x64)), str(tree)):
        h.update(part.encode())
        h.update(b"\0")
    h.update(static_bytes)
    for x in leaves:
        aval = jax.typeof(x) if hasattr(jax, "typeof") else jax.core.get_aval(x)
        h.update(f"{aval.shape}/{aval.dtype}/{getattr(aval, 'weak_type', False)};".encode())
    return h.hexdigest()


def _ready_custom_calls() -> None:
    """Load the LAPACK kernels the programs call (QR, solves). JAX does this when it lowers a
    linear-algebra op; a program loaded without lowering would call null kernels."""
    from jax._src.lax import linalg

    linalg.initialize_lapack()


def _load(path: Path, args: tuple):
    import jax
    from jax.experimental.serialize_executable import deserialize_and_load

    payload, out_tree, *flags = pickle.loads(path.read_bytes())
    if not flags or flags[0]:  # the program calls LAPACK (or was saved before this was recorded)
        _ready_custom_calls()
    return deserialize_and_load(payload, jax.tree_util.tree_structure((args, {})), out_tree)


def _save(path: Path, compiled) -> None:
    from jax.experimental.serialize_executable import serialize

    from .atomic import write_bytes

    payload, _, out_tree = serialize(compiled)
    try:
        lapack = "lapack" in compiled.as_text()
    except Exception:  # no text for this executable: assume it needs the kernels
        lapack = True
    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes(path, pickle.dumps((payload, out_tree, lapack), protocol=4))


class Stored:
    """``jitted`` (a :func:`jax.jit` function called with arrays only) through the store
    (:func:`stored`): a call with a new key loads its executable from disk, or compiles and
    saves it; later calls in the process reuse it. :meth:`prepare` starts that load or
    compile in a background thread, so that a program needed later compiles while this
    thread does other work."""

    def __init__(self, jitted: Callable, name: str, static: Any):
        self.jitted, self.name = jitted, name
        self.static_bytes = _static_bytes(static)  # once: the settings do not change between calls
        self.loaded: dict[str, Callable] = {}
        self.pending: dict[str, concurrent.futures.Future] = {}

    def __call__(self, *args):
        if self.static_bytes is None or not (ENABLED or self.loaded or self.pending):
            return self.jitted(*args)
        key = _key(self.name, self.static_bytes, args)
        fn = self.loaded.get(key)
        if fn is not None:
            return fn(*args)
        with _LOCK:
            future = self.pending.pop(key, None)
        if future is None and not ENABLED:
            return self.jitted(*args)
        fn, path = future.result() if future is not None else _fetch(self.jitted, key, args)
        return self._first_run(key, fn, path, args)

    def prepare(self, *args) -> None:
        """Load or compile the program for arguments shaped as ``args`` in a background
        thread (:func:`_compile_thread`), unless it is loaded or under way; the
        call with such arguments then waits for it instead of compiling again. Where the
        store is off (:data:`ENABLED`: library calls) the program is compiled, not stored,
        and JAX's own cache serves as usual. A failed compile is raised by that call, as it
        would have been."""
        if self.static_bytes is None:
            return
        try:  # only ever a head start: arguments it cannot key, or a process shutting down, skip it
            key = _key(self.name, self.static_bytes, args)
            with _LOCK:
                if key in self.loaded or key in self.pending:
                    return
                job = (_fetch, self.jitted, key, args) if ENABLED else (_compile, self.jitted, args)
                self.pending[key] = _compile_thread().submit(*job)
        except Exception:
            return

    def _first_run(self, key: str, fn: Callable, path: Path | None, args: tuple):
        import jax

        if path is None:  # compiled here (or plain jit): it runs as any program does
            self.loaded[key] = fn
            return fn(*args)
        try:  # the first run of a program read from disk is checked before it is trusted
            out = jax.block_until_ready(fn(*args))
        except Exception:  # arguments it does not take, a kernel it cannot find
            path.unlink(missing_ok=True)
            self.loaded[key] = self.jitted
            return self.jitted(*args)
        self.loaded[key] = fn
        return out


def stored(jitted: Callable, name: str, static: Any) -> Stored:
    """``jitted`` (a :func:`jax.jit` function called with arrays only) through the store:
    the first call with a new key loads its executable from disk, or compiles and saves it;
    later calls in the process reuse it. ``name`` and ``static`` (picklable) must
    determine, with the source, everything the function closes over. Call it with
    concrete arrays, not under a transformation (use ``jitted`` there)."""
    return Stored(jitted, name, static)


@functools.lru_cache(maxsize=1)
def _compile_thread() -> concurrent.futures.ThreadPoolExecutor:
    """The :data:`COMPILE_THREADS` background threads that :meth:`Stored.prepare` compiles
    in (their work is finished before the process exits)."""
    return concurrent.futures.ThreadPoolExecutor(max_workers=COMPILE_THREADS, thread_name_prefix="bubblefit-compile")


def _compile(jitted: Callable, args: tuple) -> tuple[Callable, None]:
    """``jitted`` compiled for ``args`` (JAX's persistent cache used as configured), as :func:`_fetch` answers."""
    return jitted.lower(*args).compile(), None


def _fetch(jitted: Callable, key: str, args: tuple) -> tuple[Callable, Path | None]:
    """The executable for ``key`` and the file it was read from: from disk, else compiled
    (and saved when it can be; the path is then None)."""
    folder = _folder()
    path = folder / f"{key}.bin" if folder is not None else None
    if path is not None and path.is_file():
        try:
            return _load(path, args), path
        except Exception:  # damaged or from an incompatible build: compile afresh
            pass
    if path is None:
        return jitted, None
    # An executable that XLA:CPU itself loaded from the persistent cache does not serialise
    # whole (its fused kernels are missing when loaded again), so compile this one afresh.
    with _persistent_cache(False):
        compiled = jitted.lower(*args).compile()
    try:
        _save(path, compiled)
        _prune(path.parent)
    except Exception:  # closed-over constants, a read-only disk: keep it in memory only
        pass
    return compiled, None


@contextlib.contextmanager
def _persistent_cache(on: bool):
    """Context in which this thread's compiles use JAX's persistent compilation cache
    (``on``) or bypass it; other threads' compiles are not affected.

    JAX decides once per process whether the cache is used (``is_cache_used``), so its
    flag cannot turn it off later: the check is wrapped, once, by one that answers False
    in a thread inside ``_persistent_cache(False)``."""
    if on:
        yield
        return
    from jax._src import compilation_cache

    with _LOCK:
        if not getattr(compilation_cache.is_cache_used, "bubblefit_bypass", False):
            used = compilation_cache.is_cache_used

            def is_cache_used(backend):
                return False if getattr(_THREAD, "bypass", False) else used(backend)

            is_cache_used.bubblefit_bypass = True
            compilation_cache.is_cache_used = is_cache_used
    before = getattr(_THREAD, "bypass", False)
    _THREAD.bypass = True
    try:
        yield
    finally:
        _THREAD.bypass = before


def _prune(folder: Path, limit_bytes: int = MAX_BYTES) -> None:
    """Delete the least recently used executables while the folder holds over ``limit_bytes``."""
    files = sorted(folder.glob("*.bin"), key=lambda p: p.stat().st_atime)
    total = sum(p.stat().st_size for p in files)
    for old in files:
        if total <= limit_bytes:
            break
        total -= old.stat().st_size
        old.unlink(missing_ok=True)
