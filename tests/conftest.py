"""Shared fixtures: shipped data, small environment maps, float64 on demand."""

from __future__ import annotations

import ctypes
import gc
import os
import sys
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax
import numpy as np
import pytest

# A persistent compilation cache keeps repeated test runs fast.
_cache = Path(os.environ.get("BUBBLEFIT_TEST_CACHE", Path(__file__).resolve().parent.parent / ".jax_cache"))
try:
    _cache.mkdir(exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(_cache))
    # every program goes into it (as the command line does, bubblefit.io.jaxcache): the
    # compiled programs are dropped after each test module (below), and one that a later
    # module needs again is loaded (milliseconds) rather than compiled
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
except OSError:
    pass

DATA = Path(__file__).resolve().parent.parent / "bubblefit" / "data"
SHARED_ENVMAPS = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "envmaps"


@pytest.fixture(scope="session")
def courtyard_pixels() -> np.ndarray:
    """The shipped courtyard map (1024x512, linear, with a sun)."""
    from bubblefit.io.images import read_image

    return read_image(DATA / "courtyard.exr").pixels


@pytest.fixture(scope="session")
def small_courtyard(courtyard_pixels) -> np.ndarray:
    """The courtyard map downsampled (power-preserving) to 64x128."""
    from bubblefit.lighting.envmap import downsample

    px = courtyard_pixels
    while px.shape[0] > 64:
        px = downsample(px)
    return px


def _package_caches():
    """The ``functools.lru_cache`` functions of the loaded ``bubblefit`` modules, except the
    one-entry ones (the source digest, the compile thread pool: no programs in them)."""
    found = {}
    for name, module in list(sys.modules.items()):
        if module is None or not (name == "bubblefit" or name.startswith("bubblefit.")):
            continue
        for value in list(vars(module).values()):
            info = getattr(value, "cache_info", None)
            if callable(info) and hasattr(value, "cache_clear") and info().maxsize != 1:
                found[id(value)] = value
    return list(found.values())


@pytest.fixture(scope="module", autouse=True)
def _compiled_programs_dropped():
    """JAX keeps every program it compiles for the life of the process, and the package
    keeps the jitted and stored programs it builds per configuration in ``lru_cache``s
    (with the executables they loaded): after a test module both are emptied (with the
    arrays only they held), so the suite's memory is that of its largest module rather
    than the sum of all of them. After ``test_fit.py``, JAX's caches alone left 1.23 GB
    resident and the package's caches held 0.57 GB of it."""
    yield
    for cached in _package_caches():
        cached.cache_clear()
    jax.clear_caches()
    gc.collect()
    _heap_trimmed()


def _heap_trimmed() -> None:
    """Hand the C heap's free pages back to the system (glibc's ``malloc_trim``; nothing
    elsewhere): freed arrays otherwise stay in the process's resident memory, and the
    next module's allocations, of other sizes, do not always fit in them. After the fast
    part of ``test_filtering.py`` (0.66 GB at its peak, programs loaded from the cache) the
    process keeps 0.42 GB resident without it and 0.27 GB with it."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


@pytest.fixture(autouse=True)
def _environment_restored():
    """Each test starts from the environment the session started with: a command run in
    this process (``bubblefit.cli.main``) sets JAX's variables for its workers
    (:func:`bubblefit.io.jaxcache.jax_setup`), which would otherwise pass on to the
    processes later tests start."""
    saved = dict(os.environ)
    yield
    if os.environ != saved:
        os.environ.clear()
        os.environ.update(saved)


@pytest.fixture
def x64():
    """Run a test in float64."""
    with jax.enable_x64(True):
        yield
