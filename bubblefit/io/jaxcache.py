"""JAX's persistent compilation cache on disk, and quiet XLA logs: one set-up for all.

The command line, the sequence workers (local or on a Dask cluster) and the scripts call
:func:`jax_setup` once per process. It works before or after JAX is imported and never
imports JAX itself: the settings go into the environment variables JAX reads when it is
first imported (``JAX_COMPILATION_CACHE_DIR`` and friends) and, if JAX is already loaded,
into ``jax.config`` as well. Commands that never compile (``chart``, ``check-capture``,
``--help``) therefore pay nothing for it.

XLA's C++ log (e.g. the "slow compile" alarm) goes to stderr unless
``TF_CPP_MIN_LOG_LEVEL`` is set before the library loads; :func:`jax_setup` sets it to
errors-only-if-fatal (``3``) unless the user chose a level, so that the user sees only
bubblefit's own lines (docs/design.md, "Command line").

XLA:CPU hands small reductions to YNNPACK, one fusion each; a fit's local solves run
faster without them, and a sequence's per-pixel map programs slower (docs/speed-profile.md),
so the solves' programs are compiled with :func:`ynn_fusions_off_option` where the installed
jaxlib is one known to accept it; every other program keeps XLA's defaults, and a setting of
the flag in the user's ``XLA_FLAGS`` is kept for all of them.
"""

from __future__ import annotations

import logging
import os
import sys
import threading

__all__ = ["default_cache_dir", "jax_setup", "jax_settings", "private_folder", "store_enabled", "warn_once",
           "ynn_fusion_setting", "ynn_fusions_off_option"]

#: Every compiled program goes into the cache (seconds of compile time below which one
#: would not). A fit builds ~160 small programs (geometry, tables, bounds) that compile in
#: 10-30 ms each but load in ~5 ms: with a threshold of 0.2 s a warm 320x320 fit spent
#: 3.5 s recompiling them; with 0 it spends 0.9 s loading everything.
MIN_COMPILE_TIME_S = 0.0


#: XLA's flag that chooses which fusions XLA:CPU hands to YNNPACK (empty: none).
YNN_FLAG = "--xla_cpu_experimental_ynn_fusion_type"
#: The jaxlib versions (first, last; inclusive) known to accept :data:`YNN_FLAG`: the ones
#: the fit was measured and validated with. The option is an experimental one of XLA's
#: ``DebugOptions``, which another jaxlib may not have (or may read otherwise), so it is
#: never given to a jaxlib outside this range.
YNN_FLAG_JAXLIB = ((0, 10, 2), (0, 10, 2))


def _version_tuple(version: str) -> tuple[int, ...] | None:
    """``"0.10.2"`` as ``(0, 10, 2)``; None for a version that is not plain numbers (a
    development build, ``0.10.3.dev20260101``: not one known)."""
    try:
        return tuple(int(part) for part in version.split("."))
    except ValueError:
        return None


def _jaxlib_version() -> str | None:
    """The installed jaxlib's version, read without importing it; None when it is not installed.

    The version is the name of the package's ``jaxlib-VERSION.dist-info`` folder beside it
    (PEP 427's layout of an installed wheel; ``importlib.metadata`` finds the same by
    reading every installed package's metadata, 25 ms of CPU at each command's start)."""
    jaxlib = sys.modules.get("jaxlib")
    if jaxlib is not None and getattr(jaxlib, "__version__", None):
        return jaxlib.__version__
    import glob
    import importlib.util

    try:
        spec = importlib.util.find_spec("jaxlib")
    except (ImportError, ValueError):
        return None
    if spec is None:
        return None
    for place in spec.submodule_search_locations or ():
        found = glob.glob(os.path.join(glob.escape(os.path.dirname(place)), "jaxlib-*.dist-info"))
        if len(found) == 1:
            return os.path.basename(found[0])[len("jaxlib-"):-len(".dist-info")]
    from importlib import metadata

    try:
        return metadata.version("jaxlib")
    except metadata.PackageNotFoundError:
        return None


def ynn_fusion_setting(xla_flags: str | None = None) -> str | None:
    """The value ``XLA_FLAGS`` (or ``xla_flags``) gives :data:`YNN_FLAG`; None when it does
    not set it.

    References
    ----------
    XLA's flag parser (``tsl/util/command_line_flags.cc``) sets the flags in the order
    given, so of a flag given twice the last value holds; a flag without ``=`` is a
    boolean's ``true``.
    """
    flags = os.environ.get("XLA_FLAGS", "") if xla_flags is None else xla_flags
    value = None
    for flag in flags.split():
        name, eq, rest = flag.partition("=")
        if name == YNN_FLAG:
            value = rest if eq else "true"
    return value


def ynn_fusions_off_option(jaxlib_version: str | None = None) -> tuple:
    """XLA's compiler option that hands no fusion to YNNPACK, ``(("xla_cpu_experimental_ynn_fusion_type",
    ""),)``, for a program's ``compiler_options``; ``()`` when the installed jaxlib (or
    ``jaxlib_version``) is not in :data:`YNN_FLAG_JAXLIB`, or when ``XLA_FLAGS`` sets the
    flag (the user's choice then holds for every program).

    References
    ----------
    XLA's ``DebugOptions.xla_cpu_experimental_ynn_fusion_type`` (xla/xla.proto); the
    measurements in docs/speed-profile.md.
    """
    if ynn_fusion_setting() is not None:
        return ()
    version = _version_tuple(jaxlib_version or _jaxlib_version() or "")
    first, last = YNN_FLAG_JAXLIB
    if version is None or not first <= version <= last:
        return ()
    return ((YNN_FLAG.lstrip("-"), ""),)


def default_cache_dir() -> str:
    """``$BUBBLEFIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/bubblefit/jax`` (``~/.cache/...``)."""
    return os.environ.get("BUBBLEFIT_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "bubblefit", "jax")


#: Cache folders refused in this process (:func:`private_folder`): neither JAX's cache nor
#: the store of executables uses them, and :func:`jax_settings` does not pass them on.
_REFUSED: set[str] = set()


def private_folder(path: str | os.PathLike) -> str | None:
    """Create ``path`` (and missing parents) with mode ``0700`` and check that no one but
    this user can change what is in it; None when it is private, else the reason in a few
    words (for the one-line warning that the cache is not used).

    The cache holds compiled programs (native code that this process runs), so a folder
    owned by another user, or writable by the group or by others, is never used: a file
    planted there could run as the user. Links are followed (the folder they point to is
    checked).

    References
    ----------
    The same rule as OpenSSH's ``StrictModes`` for ``~/.ssh``: the owner only may write.
    """
    path = os.fspath(path)
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        st = os.stat(path)
    except OSError as exc:
        return f"cannot create {path}: {(exc.strerror or str(exc)).lower()}"
    import stat

    if not stat.S_ISDIR(st.st_mode):
        return f"{path} is not a folder"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return f"{path} belongs to another user"
    if st.st_mode & 0o022:
        return f"{path} is writable by others (chmod 700 {path})"
    return None


def _drop_empty_entries(cache: str) -> None:
    """Delete JAX's cache entries of zero bytes (left by a full disk; JAX never replaces an
    entry that exists, so they would stay)."""
    try:
        with os.scandir(cache) as entries:
            for entry in entries:
                if entry.name.endswith("-cache") and entry.is_file(follow_symlinks=False) and \
                        entry.stat(follow_symlinks=False).st_size == 0:
                    os.unlink(entry.path)
    except OSError:
        pass


def _quiet_logs() -> None:
    import warnings

    # JAX warns once per program about a cache entry it cannot write or read (a full disk
    # gave 21 lines); the store reports such errors once itself (warn_once)
    warnings.filterwarnings("ignore", message=r"Error (reading|writing) persistent compilation cache entry")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")  # XLA's C++ log: nothing below fatal
    os.environ.setdefault("GLOG_minloglevel", "3")
    for name in ("jax._src.xla_bridge", "jax._src.compiler", "jax._src.compilation_cache",
                 "jax._src.cache_key"):
        logging.getLogger(name).setLevel(logging.ERROR)


_STORE_ON = False
_WARN_LOCK = threading.Lock()
_WARNED: set[str] = set()


def store_enabled() -> bool:
    """Whether this process called :func:`jax_setup`, which turns the store of compiled
    executables (:mod:`bubblefit.io.executables`) on; library calls jit as usual."""
    return _STORE_ON


def warn_once(topic: str, message: str) -> None:
    """Print ``bubblefit: warning: <message>`` on stderr the first time a ``topic`` comes up
    in this process (a full disk is one line, not one per program)."""
    with _WARN_LOCK:
        if topic in _WARNED:
            return
        _WARNED.add(topic)
    print(f"bubblefit: warning: {message}", file=sys.stderr)


def jax_setup(cache_dir: str | None = None, *, enable_x64: bool | None = None, quiet: bool = True) -> dict:
    """Configure this process's JAX: persistent compilation cache, float64, quiet logs, and
    the store of compiled executables (:mod:`bubblefit.io.executables`) turned on.

    Parameters
    ----------
    cache_dir
        Folder of the persistent compilation cache; default ``$BUBBLEFIT_CACHE_DIR``,
        else ``$JAX_COMPILATION_CACHE_DIR``, else :func:`default_cache_dir`.
        A folder that cannot be created only costs time (no cache), never an error.
    enable_x64
        Set ``jax_enable_x64``; ``None`` leaves it as it is.
    quiet
        Silence XLA's C++ log and JAX's informational Python logs.

    Returns
    -------
    dict
        ``{"cache_dir": ..., "enable_x64": ...}``: the settings, to pass to
        :func:`jax_setup` in worker processes so they share the cache.
    """
    if quiet:
        _quiet_logs()
    global _STORE_ON
    _STORE_ON = True
    cache = (cache_dir or os.environ.get("BUBBLEFIT_CACHE_DIR") or os.environ.get("JAX_COMPILATION_CACHE_DIR")
             or default_cache_dir())
    problem = private_folder(cache)
    if problem:  # no cache: every run compiles, and nothing anyone else wrote is run
        warn_once("cache", f"not using the compilation cache: {problem}")
        _REFUSED.add(os.path.abspath(cache))
        cache = None
        os.environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    else:
        _drop_empty_entries(cache)
    if cache:
        os.environ["JAX_COMPILATION_CACHE_DIR"] = cache
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", str(MIN_COMPILE_TIME_S))
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
    if enable_x64 is not None:
        os.environ["JAX_ENABLE_X64"] = "1" if enable_x64 else "0"
    jax = sys.modules.get("jax")
    if jax is not None:  # already imported: the environment is read; set the config too
        try:
            jax.config.update("jax_compilation_cache_dir", cache)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
            jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
            if enable_x64 is not None:
                jax.config.update("jax_enable_x64", bool(enable_x64))
        except Exception:  # an older or newer JAX without one of the options: no cache
            pass
    x64 = enable_x64
    if x64 is None:
        x64 = bool(jax.config.jax_enable_x64) if jax is not None else \
            os.environ.get("JAX_ENABLE_X64", "0").lower() in ("1", "true")
    return {"cache_dir": cache, "enable_x64": x64}


def jax_settings() -> dict:
    """This process's JAX settings that worker processes should share, read without changing
    them: ``{"cache_dir": ..., "enable_x64": ...}`` for :func:`jax_setup` in the workers.
    The cache folder is JAX's configured one, else the environment's, else :func:`default_cache_dir`."""
    jax = sys.modules.get("jax")
    cache, x64 = None, None
    if jax is not None:
        cache = getattr(jax.config, "jax_compilation_cache_dir", None)
        x64 = bool(jax.config.jax_enable_x64)
    if x64 is None:
        x64 = os.environ.get("JAX_ENABLE_X64", "0").lower() in ("1", "true")
    cache = cache or os.environ.get("JAX_COMPILATION_CACHE_DIR") or default_cache_dir()
    return {"cache_dir": None if os.path.abspath(cache) in _REFUSED else cache, "enable_x64": x64}
