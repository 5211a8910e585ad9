"""Compiled programs kept on disk, so that a new process does not trace them again.

JAX's persistent compilation cache (:mod:`bubblefit.io.jaxcache`) saves XLA's compile,
but its key is the lowered program: every process still traces the Python function to a
jaxpr and lowers it to MLIR before it can look the program up. For the fit's
Levenberg-Marquardt solve (the render, its Jacobian, the trust region and the QR inside
one ``while_loop``) that is about 0.5 s of tracing and 0.3 s of lowering per program,
every process. :func:`stored` keeps the compiled executable itself under a key computed
without tracing:

- what the function is: a name and the static values it closes over (the render
  configuration, the parameter table, the solver's settings), serialised for the key only;
- the code it runs: a digest of every ``.py`` file of the bubblefit package, and the
  versions of JAX and jaxlib, the backend, the float64 flag and the XLA:CPU fusions chosen
  (:func:`bubblefit.io.jaxcache.ynn_fusion_setting`);
- what it is called with: the arguments' tree structure, shapes and dtypes.

A change to any of them is a new key, so a stale program is never run.

What a file holds, and why nothing in it but XLA's program is ever run: no Python object is
unpickled (JAX's own :mod:`jax.experimental.serialize_executable` pickles, so it is not
used). A file is :data:`MAGIC`, a JSON header of plain data (the key, the input and output
shapes and dtypes, the arguments the program keeps, the output tree as JAX's protocol-buffer
description, which names no Python type), XLA's serialised executable as the backend
writes it, and an HMAC-SHA256 of all that under a random key that the store created in its
own folder (``.key``, mode ``0600``). The folders are created ``0700`` and not used when
another user owns them or others can write them (:func:`bubblefit.io.jaxcache.private_folder`),
so no one else can place a program there; a file whose digest, length or key does not
match (planted, copied from another cache, cut short by a full disk) is ignored and
replaced by a fresh compile. Programs the format cannot describe (closed-over constants,
effects, host callbacks, several devices, user-defined output nodes) stay in memory only.

Any failure to store, to load or to run a loaded program the first time falls back to the
plain jitted call; a failed write (full or read-only disk) is reported once per process.
Files live in ``executables/`` of the compilation cache's folder (at most
:data:`MAX_BYTES`). The store is used in processes that called
:func:`~bubblefit.io.jaxcache.jax_setup` (the command line and its workers).

A program needed later can be started ahead (:meth:`Stored.prepare`): unless the store
holds it already (then its call loads it), it is compiled in a background thread
(:data:`COMPILE_THREADS` of them) while the caller goes on, and the call with arguments
of the same shapes waits for it (the fit prepares its final solve, its final render and
its standard errors' programs before the global search).

Two things XLA:CPU needs, found by running it: an executable is serialised from a fresh
compile (one that the persistent cache loaded loses its fused kernels, and JAX's in-memory
cache hands back such a one when the process already called the function plainly, so the
store's compile carries :data:`FRESH_COMPILE`), and the LAPACK
kernels are initialised before a loaded program runs (JAX does it while lowering, which a
loaded program skips).

The store compiles a program without its source locations (:func:`_strip_locations`):
XLA would keep each instruction's traced name and source line in the executable, about
two fifths of the file, which every load parses again and no computation reads.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import functools
import hashlib
import hmac
import json
import os
import pickle
import secrets
import stat
import sys
import threading
from pathlib import Path
from typing import Any, Callable

from .atomic import os_reason
from .jaxcache import jax_settings, private_folder, store_enabled, warn_once, ynn_fusion_setting

__all__ = ["Stored", "deferred", "stored", "source_digest", "wait_for_compiles"]

#: Folder, under the compilation cache's, that holds the stored executables.
FOLDER = "executables"
#: Most bytes the folder keeps (a fit's solves of a 320x320 photo are 1.2-8.5 MB); the least
#: recently used go first.
MAX_BYTES = 512 * 2**20
#: Background threads that :meth:`Stored.prepare` compiles in. Two: a fit prepares its final
#: solve and its final render, and with one thread the render's compile queued behind the
#: solve's, the longest on an empty cache's first fit, while the fit itself waited.
COMPILE_THREADS = 2
#: Whether :func:`stored` uses the store; None (the default): when this process called
#: :func:`bubblefit.io.jaxcache.jax_setup` (the command line, the sequence workers), so that
#: library calls without it jit as usual.
ENABLED: bool | None = None
_LOCK = threading.Lock()
#: First bytes of a stored executable's file, with the version of its layout.
MAGIC = b"bubblefit-executable\n"
#: Version of the header's fields.
FORMAT = 1
#: Length of the store's key (:func:`_secret`).
SECRET_BYTES = 32
#: Largest file the store reads (a fit's solves of a 320x320 photo are 1.2-8.5 MB): a larger
#: one is not its own.
MAX_FILE_BYTES = 256 * 2**20
#: An XLA option at its default value (embedding the HLO text in the executable, off),
#: passed to the store's compiles: the program is the same, but the option is part of the
#: key of JAX's in-memory cache of compiled programs, so the store never receives an
#: executable that an earlier plain call loaded from the persistent cache (found by
#: running it: the file stored from such a program failed its first run in every later
#: process, which then compiled it again).
FRESH_COMPILE = (("xla_embed_ir_in_executable", False),)
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
    """The store's folder, created private (``0700``); None (no store, a warning once) when
    the cache is off or the folder is not private to this user
    (:func:`bubblefit.io.jaxcache.private_folder`)."""
    import jax

    cache = getattr(jax.config, "jax_compilation_cache_dir", None) or jax_settings()["cache_dir"]
    if not cache:
        return None
    folder = Path(cache) / FOLDER
    problem = private_folder(cache) or private_folder(folder)
    if problem:
        warn_once("store", f"not using the compiled-program store: {problem}")
        return None
    _guard_jax_cache()
    return folder


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
                 str(jax.devices()[0].device_kind), str(bool(jax.config.jax_enable_x64)),
                 f"ynn={ynn_fusion_setting()}", str(tree)):
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


class StoreError(Exception):
    """A file of the store that is not one this store wrote whole: it is ignored and replaced."""


def _secret(folder: Path) -> bytes:
    """The store's key for its digests: :data:`SECRET_BYTES` random bytes in ``folder/.key``,
    created once, readable by the owner only (``0600``). A key file that is not the owner's
    own, is readable or writable by others, or is not the right length makes the store
    unusable (:class:`StoreError`): nothing in the folder is trusted then."""
    path = folder / ".key"
    if not os.path.lexists(path):  # written whole under another name, then linked: never seen half-written
        tmp = folder / f".key.{secrets.token_hex(8)}"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), 0o600)
        try:
            try:
                if os.write(fd, secrets.token_bytes(SECRET_BYTES)) != SECRET_BYTES:
                    raise OSError(28, "No space left on device")
                os.fsync(fd)
            finally:
                os.close(fd)
            os.link(tmp, path)  # fails if another process made its key first: that one is used
        except FileExistsError:
            pass
        finally:
            tmp.unlink(missing_ok=True)
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or stat.S_IMODE(st.st_mode) & 0o077 or \
                (hasattr(os, "getuid") and st.st_uid != os.getuid()):
            raise StoreError(f"{path} is not private to this user")
        key = os.read(fd, SECRET_BYTES + 1)
    finally:
        os.close(fd)
    if len(key) != SECRET_BYTES:
        path.unlink(missing_ok=True)  # a key cut short (a full disk): a new one next time
        raise StoreError(f"{path} is damaged")
    return key


def _avals(avals) -> list:
    """Shapes, dtypes and weak-type flags of abstract values, as JSON."""
    return [[list(a.shape), str(a.dtype), bool(getattr(a, "weak_type", False))] for a in avals]


def _shaped(described) -> list:
    import numpy as np
    from jax._src import core

    return [core.ShapedArray(tuple(int(d) for d in shape), np.dtype(dtype), weak_type=bool(weak))
            for shape, dtype, weak in described]


def _describe(compiled, key: str) -> tuple[dict, bytes]:
    """The header (plain data) and XLA's serialised executable of ``compiled``, or
    :class:`StoreError` for a program the store does not keep: one with closed-over
    constants, effects, host callbacks, mutable references or several devices, or whose
    output tree holds a node type other than tuple, list, dict and None (the tree is
    stored as JAX's own protocol-buffer description, which carries no code)."""
    import base64

    from jax._src.sharding_impls import SingleDeviceSharding

    u = getattr(compiled._executable, "_unloaded_executable", None)
    if u is None or compiled._params.const_args or u.mut is not None or u.unordered_effects or \
            u.ordered_effects or u.host_callbacks or u.keepalive or len(u.device_list) != 1:
        raise StoreError("not a plain single-device program")
    if not all(isinstance(s, SingleDeviceSharding) for s in (*u.input_shardings, *u.output_shardings)):
        raise StoreError("not a single-device program")
    try:
        out_tree = compiled.out_tree.serialize_using_proto()
    except Exception as exc:  # a user-defined node in the output
        raise StoreError(str(exc)) from None
    try:
        lapack = "lapack" in compiled.as_text()
    except Exception:  # no text for this executable: assume it needs the kernels
        lapack = True
    payload = bytes(u.backend.serialize_executable(u.xla_executable))
    header = {"format": FORMAT, "key": key, "name": u.name, "in": _avals(u.input_avals),
              "out": _avals(u.output_avals), "kept": sorted(int(i) for i in u.kept_var_idx),
              "committed": bool(u.committed), "no_kwargs": bool(compiled._no_kwargs),
              "out_tree": base64.b64encode(out_tree).decode("ascii"), "lapack": bool(lapack),
              "payload_bytes": len(payload)}
    return header, payload


def _pack(header: dict, payload: bytes, secret: bytes) -> bytes:
    """The file's bytes: :data:`MAGIC`, the header's length (8 bytes, big-endian), the JSON
    header, XLA's executable, and the HMAC-SHA256 under the store's key of all before it."""
    head = json.dumps(header, sort_keys=True, separators=(",", ":")).encode("utf-8")
    body = MAGIC + len(head).to_bytes(8, "big") + head + payload
    return body + hmac.new(secret, body, hashlib.sha256).digest()


def _unpack(data: bytes, key: str, secret: bytes) -> tuple[dict, bytes]:
    """Header and executable of a file's bytes, after its digest, its length and its key
    are checked (:class:`StoreError` otherwise: a truncated, damaged or foreign file)."""
    n_mac = hashlib.sha256().digest_size
    if len(data) < len(MAGIC) + 8 + n_mac or not data.startswith(MAGIC):
        raise StoreError("not a stored executable")
    body, mac = data[:-n_mac], data[-n_mac:]
    if not hmac.compare_digest(hmac.new(secret, body, hashlib.sha256).digest(), mac):
        raise StoreError("digest mismatch")
    n_head = int.from_bytes(body[len(MAGIC):len(MAGIC) + 8], "big")
    head_end = len(MAGIC) + 8 + n_head
    header = json.loads(body[len(MAGIC) + 8:head_end].decode("utf-8"))
    payload = body[head_end:]
    if header.get("format") != FORMAT or header.get("key") != key or header.get("payload_bytes") != len(payload):
        raise StoreError("header does not match")
    return header, payload


def _read_limited(path: Path) -> bytes:
    """A regular file's bytes (links not followed), at most :data:`MAX_FILE_BYTES`."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_FILE_BYTES:
            raise StoreError("not a regular file of a plausible size")
        with os.fdopen(os.dup(fd), "rb") as fh:
            return fh.read(MAX_FILE_BYTES + 1)
    finally:
        os.close(fd)


def _load(path: Path, args: tuple):
    """The program stored in ``path`` for arguments ``args``, rebuilt from the header's
    plain data and XLA's executable (deserialised by the backend itself): no Python object
    is ever unpickled. The file must carry the store's digest (:func:`_pack`)."""
    import base64

    import jax
    from jax._src import stages
    from jax._src.interpreters import pxla
    from jax._src.lib import xla_client as xc
    from jax._src.sharding_impls import SingleDeviceSharding

    header, payload = _unpack(_read_limited(path), path.stem, _secret(path.parent))
    leaves, in_tree = jax.tree_util.tree_flatten((args, {}))
    arg_avals = [jax.typeof(x) if hasattr(jax, "typeof") else jax.core.get_aval(x) for x in leaves]
    kept = set(header["kept"])
    in_avals, out_avals = _shaped(header["in"]), _shaped(header["out"])
    if _avals([a for i, a in enumerate(arg_avals) if i in kept]) != _avals(in_avals):
        raise StoreError("arguments do not match")
    if header["lapack"]:
        _ready_custom_calls()
    device = jax.devices()[0]
    backend = device.client
    devices = xc.DeviceList((device,))
    executable = backend.deserialize_executable(payload, executable_devices=devices)
    sharding = SingleDeviceSharding(device)
    in_shardings, out_shardings = [sharding] * len(in_avals), [sharding] * len(out_avals)
    xla_in, xla_out = pxla._get_layouts_from_executable(
        executable, [None] * len(in_avals), [None] * len(out_avals), 0, in_avals, out_avals)
    unloaded = pxla.UnloadedMeshExecutable(
        xla_executable=executable, device_list=devices, backend=backend, input_avals=in_avals,
        input_shardings=in_shardings, output_avals=out_avals, output_shardings=out_shardings,
        committed=header["committed"], name=header["name"], unordered_effects=[], ordered_effects=[],
        keepalive=[], host_callbacks=[], kept_var_idx=kept, mut=None, xla_in_layouts=xla_in,
        dispatch_in_layouts=pxla.get_dispatch_layouts(xla_in, in_shardings, in_avals),
        xla_out_layouts=xla_out, all_args_info=None, pgle_profiler=None)
    out_tree = jax.tree_util.PyTreeDef.deserialize_using_proto(
        jax.tree_util.default_registry, base64.b64decode(header["out_tree"]))
    args_info = in_tree.unflatten([stages.ArgInfo(a, False) for a in arg_avals])
    return stages.Compiled(unloaded.load(), [], args_info, out_tree, no_kwargs=header["no_kwargs"])


def _save(path: Path, compiled) -> None:
    """Write ``compiled`` to ``path`` in the store's format (:func:`_pack`)."""
    from .atomic import write_bytes

    header, payload = _describe(compiled, path.stem)
    if path.is_symlink():  # never written through: the link itself is replaced by the file
        path.unlink()
    write_bytes(path, _pack(header, payload, _secret(path.parent)))


def _enabled() -> bool:
    """Whether :func:`stored` uses the store: :data:`ENABLED` when set, else whether this
    process called :func:`~bubblefit.io.jaxcache.jax_setup`."""
    return store_enabled() if ENABLED is None else ENABLED


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
        if self.static_bytes is None or not (_enabled() or self.loaded or self.pending):
            return self.jitted(*args)
        key = _key(self.name, self.static_bytes, args)
        fn = self.loaded.get(key)
        if fn is not None:
            return fn(*args)
        with _LOCK:
            future = self.pending.pop(key, None)
        if future is None and not _enabled():
            return self.jitted(*args)
        fn, path = future.result() if future is not None else _fetch(self.jitted, key, args)
        return self._first_run(key, fn, path, args)

    def prepare(self, *args) -> None:
        """Compile the program for arguments shaped as ``args`` in a background thread
        (:func:`_compile_thread`), unless it is loaded, under way or already in the store;
        the call with such arguments then waits for it instead of compiling again. A
        stored program is left to its call, which loads it: a prepared program may never
        be called (``auto``'s paper model, prepared before its search, is not solved when
        the physical model solved first is kept), and loading one costs CPU whichever
        thread does it (XLA rebuilds the program from its HLO: 1.6-1.9 s of CPU for the
        8.5 MB final solve of docs/speed.md's 320x320 photo, on 2 shared cores), whereas
        the head start only hides a compile's wait. Where the store is off
        (:data:`ENABLED`: library calls) the program is compiled, not stored, and JAX's own
        cache serves as usual. A failed compile is raised by that call, as it would have
        been."""
        if self.static_bytes is None:
            return
        try:  # only ever a head start: arguments it cannot key, or a process shutting down, skip it
            key = _key(self.name, self.static_bytes, args)
            folder = _folder() if _enabled() else None
            if folder is not None and os.path.lexists(folder / f"{key}.bin"):
                return  # stored: its call loads it, if the caller gets that far
            with _LOCK:
                if key in self.loaded or key in self.pending:
                    return
                job = (_fetch, self.jitted, key, args) if _enabled() else (_compile, self.jitted, args)
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


class _Deferred:
    """A jitted function that :func:`deferred` builds at its first call or lowering."""

    def __init__(self, make: Callable[[], Callable]):
        self.make, self.built = make, None

    def function(self) -> Callable:
        """The jitted function, built by ``make()`` at the first need."""
        if self.built is None:
            self.built = self.make()
        return self.built

    def __call__(self, *args):
        """The jitted function called (a plain call: the store is off or fell back)."""
        return self.function()(*args)

    def lower(self, *args):
        """The jitted function lowered for ``args`` (a compile: :func:`_fetch`, :func:`_compile`)."""
        return self.function().lower(*args)


def deferred(make: Callable[[], Callable]) -> Callable:
    """A jitted function for :func:`stored` that ``make()`` builds where it is first called
    or lowered, not before: a program the store holds is loaded and run without it, so
    what only its tracing needs (the local solves' optimistix, equinox and lineax, about
    0.25 s of CPU to import: :mod:`bubblefit.inverse._lm_solver`) is never imported by a
    process whose programs are all stored. ``make`` may run in a compile thread
    (:meth:`Stored.prepare`) as well as the caller's: it must give the same function
    whichever calls it (a cached builder)."""
    return _Deferred(make)


def stored(jitted: Callable, name: str, static: Any) -> Stored:
    """``jitted`` (a :func:`jax.jit` function called with arrays only) through the store:
    the first call with a new key loads its executable from disk, or compiles and saves it;
    later calls in the process reuse it. ``name`` and ``static`` (picklable) must
    determine, with the source, everything the function closes over. Call it with
    concrete arrays, not under a transformation (use ``jitted`` there)."""
    return Stored(jitted, name, static)


def wait_for_compiles() -> None:
    """Wait until the compile threads (:meth:`Stored.prepare`) have finished their work,
    the programs they compiled stored: what the interpreter's exit would wait for
    (:func:`bubblefit.cli.main` ends a command's process without that exit)."""
    if _compile_thread.cache_info().currsize:
        _compile_thread().shutdown(wait=True)
        _compile_thread.cache_clear()


@functools.lru_cache(maxsize=1)
def _compile_thread() -> concurrent.futures.ThreadPoolExecutor:
    """The :data:`COMPILE_THREADS` background threads that :meth:`Stored.prepare` compiles
    in (their work is finished before the process exits)."""
    return concurrent.futures.ThreadPoolExecutor(max_workers=COMPILE_THREADS, thread_name_prefix="bubblefit-compile")


def _compile(jitted: Callable, args: tuple) -> tuple[Callable, None]:
    """``jitted`` compiled for ``args`` (JAX's persistent cache used as configured), as :func:`_fetch` answers."""
    return jitted.lower(*args).compile(), None


def _strip_locations(lowered) -> None:
    """Drop the source locations from ``lowered``'s module (MLIR's ``strip-debuginfo`` pass)
    before the store compiles it. XLA turns each operation's location into the metadata of
    its HLO instruction (the traced function's name stack and source line), which the
    serialised executable keeps and a load parses again: the physical local solve of a
    320x320 photo is 6.1 MB without them and 10.7 MB with them (38 thousand names).
    Metadata is debugging information only: the compiled program is the same. A module
    that cannot be reached or stripped is compiled as it is."""
    try:
        from jax._src.lib.mlir import passmanager

        module = lowered._lowering._hlo
        with module.context:
            passmanager.PassManager.parse("builtin.module(strip-debuginfo)").run(module.operation)
    except Exception:
        pass


def _fetch(jitted: Callable, key: str, args: tuple) -> tuple[Callable, Path | None]:
    """The executable for ``key`` and the file it was read from: from disk, else compiled
    (and saved when it can be; the path is then None)."""
    folder = _folder()
    path = folder / f"{key}.bin" if folder is not None else None
    if path is not None and os.path.lexists(path):
        try:
            return _load(path, args), path
        except Exception:  # truncated, damaged, foreign or from another build: compiled afresh, replaced
            pass
    if path is None:
        return jitted, None
    # An executable that XLA:CPU itself loaded from the persistent cache does not serialise
    # whole (its fused kernels are missing when loaded again), so compile this one afresh:
    # past the persistent cache, and past JAX's in-memory cache of compiled programs, which
    # would hand back the program a plain call of ``jitted`` already loaded from the
    # persistent cache (:data:`FRESH_COMPILE` makes the compile's key new).
    with _persistent_cache(False):
        lowered = jitted.lower(*args)
        _strip_locations(lowered)
        compiled = lowered.compile(compiler_options=dict(FRESH_COMPILE))
    try:
        _save(path, compiled)
        _prune(path.parent)
    except StoreError:  # a program the store does not keep: in memory only
        pass
    except Exception as exc:  # a full or read-only disk: in memory only, said once
        reason = os_reason(exc) if isinstance(exc, OSError) else str(exc)
        warn_once("store-write", f"cannot write the compiled-program store in {path.parent} ({reason}); "
                                 "results are unaffected, later runs compile again")
    return compiled, None


def _guard_jax_cache() -> None:
    """Make JAX's persistent compilation cache replace its entries that cannot be read and
    report its write errors once. JAX never replaces an entry that exists: one cut short by
    a full disk would be read, fail and be compiled again in every later run. Here an entry
    that fails to load is deleted (the compile that follows writes it anew), and JAX's
    warnings about cache entries are replaced by one line per process (:func:`warn_once`)."""
    from jax._src import compilation_cache

    with _LOCK:
        if getattr(compilation_cache.get_executable_and_time, "bubblefit_guard", False):
            return
        get, put = compilation_cache.get_executable_and_time, compilation_cache.put_executable_and_time

        def get_executable_and_time(cache_key, *args, **kwargs):
            try:
                return get(cache_key, *args, **kwargs)
            except Exception:
                _remove_jax_entry(cache_key)
                return None, None

        def put_executable_and_time(*args, **kwargs):
            try:
                return put(*args, **kwargs)
            except Exception as exc:
                reason = os_reason(exc) if isinstance(exc, OSError) else f"{type(exc).__name__}: {exc}"
                warn_once("jax-cache-write", f"cannot write JAX's compilation cache ({reason}); "
                                             "results are unaffected, later runs compile again")

        get_executable_and_time.bubblefit_guard = True
        compilation_cache.get_executable_and_time = get_executable_and_time
        compilation_cache.put_executable_and_time = put_executable_and_time


def _jax_cache_dir() -> str | None:
    """The folder of JAX's persistent compilation cache in this process (None: no cache)."""
    import jax

    return getattr(jax.config, "jax_compilation_cache_dir", None)


def _remove_jax_entry(cache_key: str) -> None:
    """Delete JAX's persistent-cache entry ``cache_key`` (its ``-cache`` and ``-atime`` files)."""
    cache = _jax_cache_dir()
    if not cache or not cache_key or "/" in cache_key or cache_key.startswith("."):
        return
    for suffix in ("-cache", "-atime"):
        try:
            os.unlink(os.path.join(cache, cache_key + suffix))
        except OSError:
            pass


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
    """Delete the least recently used executables while the folder holds over ``limit_bytes``.
    Another process sharing the store may prune it at the same time: a file that is gone
    when it is read or removed is skipped, not an error."""
    entries = []
    for p in folder.glob("*.bin"):
        try:
            st = p.stat()
        except FileNotFoundError:  # removed by another process since the listing
            continue
        entries.append((st.st_atime, st.st_size, p))
    entries.sort(key=lambda e: e[0])
    total = sum(size for _, size, _ in entries)
    for _, size, old in entries:
        if total <= limit_bytes:
            break
        total -= size
        old.unlink(missing_ok=True)
