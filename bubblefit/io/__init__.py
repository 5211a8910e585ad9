"""Files: images through OpenImageIO (linear EXR/HDR, sRGB PNG/JPEG/TIFF), one atomic
write path for every output (:mod:`bubblefit.io.atomic`), JSON results, spectrometer readings
(:mod:`bubblefit.io.spectra`), and JAX's
persistent compilation cache (:mod:`bubblefit.io.jaxcache`).

The names are loaded on first use (PEP 562): the command line imports
:mod:`bubblefit.io.atomic` while it builds its parsers, and must not pay for
OpenImageIO and colour-science there.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "Image": "images", "read_image": "images", "write_image": "images", "write_preview": "images",
    "srgb_decode": "encoding", "srgb_encode": "encoding", "preview_path": "images",
    "atomic_path": "atomic", "write_text": "atomic", "write_bytes": "atomic", "write_json": "atomic",
    "json_text": "atomic",
    "jax_setup": "jaxcache", "default_cache_dir": "jaxcache",
    "Spectrum": "spectra", "read_spectrum": "spectra",
}
_MODULES = ("images", "atomic", "jaxcache", "spectra")

__all__ = sorted(_EXPORTS) + list(_MODULES)


def __getattr__(name: str):
    if name in _MODULES:
        return importlib.import_module(f".{name}", __name__)
    if name not in _EXPORTS:
        raise AttributeError(f"module 'bubblefit.io' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    globals()[name] = value
    return value
