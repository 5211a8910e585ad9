"""Spectral images: a hyperspectral cube (a spectrum per pixel) or a line scan (a spectrum
per row of an imaging spectrometer's slit), read lazily, a block of rows at a time.

Formats, each with a wavelength axis:

- ENVI: a ``.hdr`` text header (``samples``, ``lines``, ``bands``, ``data type``,
  ``interleave`` bsq/bil/bip, ``byte order``, ``header offset``, ``wavelength = {...}``,
  ``wavelength units``) beside its binary file (the ``.hdr`` path with ``.img``, ``.dat``,
  ``.raw``, ``.bin`` or no suffix); bil and bip read a block of lines at a time, bsq
  memory-mapped.
- NumPy ``.npy`` (a block of its first axis at a time, or memory-mapped when Fortran-ordered;
  the wavelengths in a ``--wavelengths`` text file, one a line) or ``.npz`` (an array ``wavelength_nm`` or ``wavelength`` and one 2-D or 3-D
  array; an ``.npz`` member is read whole when first touched).
- HDF5 (``.h5``/``.hdf5``/``.he5``, h5py) or Zarr (a ``.zarr`` folder, zarr): the first
  2-D or 3-D dataset, its wavelengths in a 1-D dataset named ``wavelength*`` or in the
  dataset's attribute ``wavelength_nm``/``wavelength``; read a chunk at a time.

The wavelength axis is the one whose length is the number of wavelengths (the last one
when several are); a 2-D array is a line scan, ``(rows, bands)``. Wavelengths are in nm,
Angstrom, um or m, read from their range as for single readings
(:func:`bubblefit.io.spectra.wavelength_unit`). Missing, non-finite or not strictly
increasing wavelengths, an axis that matches none, or fewer than
:data:`~bubblefit.io.spectra.MIN_SAMPLES` bands raise
:class:`~bubblefit.errors.InputError` with one line.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .spectra import MIN_SAMPLES, _convert_wavelengths

__all__ = ["SpectralCube", "read_cube", "is_cube_path", "CUBE_SUFFIXES"]

#: File suffixes read as spectral images (everything else is a two-column reading).
CUBE_SUFFIXES = (".hdr", ".npy", ".npz", ".h5", ".hdf5", ".he5", ".zarr")

_ENVI_TYPES = {1: "u1", 2: "i2", 3: "i4", 4: "f4", 5: "f8", 12: "u2", 13: "u4", 14: "i8", 15: "u8"}


@dataclass
class SpectralCube:
    """A spectral image: ``wavelength_nm`` (N,), increasing, and ``data``, an array-like
    (memory map, HDF5 or Zarr array) whose axes ``axes`` = (rows, columns, bands) index it
    (``columns`` None for a line scan). :meth:`rows` reads a block as float64."""

    wavelength_nm: np.ndarray
    data: object
    axes: tuple
    path: str
    unit: str = "nm"
    #: How to open it again elsewhere (a Dask worker): ``read_cube``'s path, wavelengths, unit.
    source: tuple = ()

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns) of the map; columns 1 for a line scan."""
        r, c, _ = self.axes
        return int(self.data.shape[r]), (1 if c is None else int(self.data.shape[c]))

    @property
    def is_line(self) -> bool:
        return self.axes[1] is None

    def rows(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start:stop`` as a (rows, columns, bands) float64 array."""
        r, c, b = self.axes
        index = [slice(None)] * self.data.ndim
        index[r] = slice(start, stop)
        block = np.asarray(self.data[tuple(index)], dtype=np.float64)
        if c is None:
            return (block if r < b else block.T)[:, None, :]
        return np.transpose(block, (r, c, b))


class _FileRows:
    """A C-ordered array in a file read a block of its first axis at a time by seeking,
    not memory-mapped: the resident memory is then one block's, where a memory map keeps
    every page it touched until the system needs it back."""

    def __init__(self, path: Path, dtype: np.dtype, shape: tuple, offset: int):
        self.path, self.dtype, self.shape, self.offset = path, np.dtype(dtype), tuple(shape), offset
        self.ndim = len(self.shape)

    def __getitem__(self, index):
        sl = index[0] if isinstance(index, tuple) else index
        start, stop, _ = sl.indices(self.shape[0])
        per_row = int(np.prod(self.shape[1:]))
        with open(self.path, "rb") as fh:
            fh.seek(self.offset + start * per_row * self.dtype.itemsize)
            data = np.fromfile(fh, dtype=self.dtype, count=max(stop - start, 0) * per_row)
        return data.reshape((max(stop - start, 0), *self.shape[1:]))


def _npy(path: Path):
    """A ``.npy`` array: read by seeking when C-ordered (:class:`_FileRows`), else memory-mapped."""
    with open(path, "rb") as fh:
        version = np.lib.format.read_magic(fh)
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, fortran, dtype = read(fh)
        offset = fh.tell()
    if fortran or dtype.hasobject:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    return _FileRows(path, dtype, shape, offset)


def is_cube_path(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a spectral image (by its suffix, :data:`CUBE_SUFFIXES`)."""
    return Path(path).suffix.lower() in CUBE_SUFFIXES


def _check_wavelengths(lam, what: str, unit: str | None) -> tuple[np.ndarray, str]:
    lam = np.asarray(lam, dtype=np.float64).ravel()
    if lam.size < MIN_SAMPLES:
        raise InputError(f"{what}: {lam.size} wavelengths; need at least {MIN_SAMPLES}")
    if not np.all(np.isfinite(lam)):
        raise InputError(f"{what}: the wavelengths are not all finite numbers")
    if not np.all(np.diff(lam) > 0):
        raise InputError(f"{what}: the wavelengths do not increase strictly along the band axis")
    return _convert_wavelengths(lam, unit, what)


def _axes(shape: tuple, bands: int, what: str) -> tuple:
    """(rows, columns, bands) axes of an array of ``shape`` with ``bands`` wavelengths."""
    if len(shape) not in (2, 3):
        raise InputError(f"{what}: a {len(shape)}-D array; a cube is 3-D (rows, columns, bands) and a line scan "
                         "2-D (rows, bands)")
    match = [i for i, s in enumerate(shape) if s == bands]
    if not match:
        raise InputError(f"{what}: no axis of the array {tuple(shape)} has the {bands} wavelengths")
    b = match[-1]
    rest = [i for i in range(len(shape)) if i != b]
    return (rest[0], rest[1], b) if len(shape) == 3 else (rest[0], None, b)


def _read_envi_header(path: Path) -> dict:
    text = path.read_text(errors="replace")
    if not text.lstrip().upper().startswith("ENVI"):
        raise InputError(f"cube {path}: not an ENVI header (its first word is not ENVI)")
    fields = {}
    for m in re.finditer(r"^\s*([^=\n]+?)\s*=\s*(\{[^}]*\}|[^\n]*)", text, flags=re.M):
        fields[m.group(1).strip().lower()] = m.group(2).strip()
    return fields


def _envi(path: Path, unit: str | None) -> SpectralCube:
    h = _read_envi_header(path)
    what = f"cube {path}"
    try:
        samples, lines, bands = (int(h[k]) for k in ("samples", "lines", "bands"))
        dtype = np.dtype(_ENVI_TYPES[int(h.get("data type", "4"))])
    except (KeyError, ValueError):
        raise InputError(f"{what}: the header lacks samples, lines, bands or a known data type") from None
    if "wavelength" not in h:
        raise InputError(f"{what}: the header has no wavelength = {{...}} list (the band axis's wavelengths)")
    try:
        lam = [float(v) for v in h["wavelength"].strip("{} ").split(",") if v.strip()]
    except ValueError:
        raise InputError(f"{what}: the header's wavelength list is not numbers") from None
    if len(lam) != bands:
        raise InputError(f"{what}: {len(lam)} wavelengths for {bands} bands")
    units = h.get("wavelength units", "").strip().lower()
    forced = {"nanometers": "nm", "nm": "nm", "micrometers": "um", "microns": "um", "um": "um",
              "angstroms": "Angstrom", "meters": "m"}.get(units, unit)
    lam_nm, used = _check_wavelengths(lam, what, unit or forced)
    if int(h.get("byte order", "0")) == 1:
        dtype = dtype.newbyteorder(">")
    binary = next((c for c in (path.with_suffix(s) for s in (".img", ".dat", ".raw", ".bin", "")) if c.is_file()
                   and c != path), None)
    if binary is None:
        raise InputError(f"{what}: no binary file beside the header ({path.stem}.img, .dat, .raw or .bin)")
    offset = int(h.get("header offset", "0"))
    interleave = h.get("interleave", "bsq").lower()
    shapes = {"bsq": ((bands, lines, samples), (1, 2, 0)), "bil": ((lines, bands, samples), (0, 2, 1)),
              "bip": ((lines, samples, bands), (0, 1, 2))}
    if interleave not in shapes:
        raise InputError(f"{what}: interleave {interleave!r} is none of bsq, bil, bip")
    shape, axes = shapes[interleave]
    need = offset + int(np.prod(shape)) * dtype.itemsize
    if binary.stat().st_size < need:
        raise InputError(f"{what}: {binary.name} has {binary.stat().st_size} bytes; the header asks for {need}")
    if interleave == "bsq":  # a row of the image is spread over the file: memory-mapped
        data = np.memmap(binary, dtype=dtype, mode="r", offset=offset, shape=shape)
    else:
        data = _FileRows(binary, dtype, shape, offset)
    return SpectralCube(lam_nm, data, axes, str(path), used, (str(path), None, unit))


def _named(arrays: dict, what: str):
    """The wavelengths and the data array of a mapping of named arrays (npz, HDF5, Zarr)."""
    lam_key = next((k for k in arrays if k.lower().startswith("wavelength") and len(arrays[k].shape) == 1), None)
    data_key = next((k for k in arrays if len(arrays[k].shape) in (2, 3)), None)
    if data_key is None:
        raise InputError(f"{what}: no 2-D or 3-D array in it (a cube or a line scan)")
    lam = arrays[lam_key][...] if lam_key is not None else None
    if lam is None:
        attrs = getattr(arrays[data_key], "attrs", {})
        for key in ("wavelength_nm", "wavelength", "wavelengths"):
            if key in attrs:
                lam = np.asarray(attrs[key])
                break
    if lam is None:
        raise InputError(f"{what}: no wavelength axis (a 1-D array named wavelength_nm, or the data's attribute "
                         "wavelength_nm)")
    return lam, arrays[data_key]


def read_cube(path: str | os.PathLike, *, wavelengths: str | os.PathLike | None = None,
              unit: str | None = None) -> SpectralCube:
    """Open a spectral image (see the module for the formats); ``wavelengths`` is the text
    file of a ``.npy`` cube's wavelengths, ``unit`` forces their unit."""
    p = Path(path)
    what = f"cube {p}"
    ext = p.suffix.lower()
    if not p.exists():
        raise InputError(f"{what}: no such file")
    try:
        if ext == ".hdr":
            return _envi(p, unit)
        if ext == ".npy":
            data = _npy(p)
            if wavelengths is None:
                raise InputError(f"{what}: a .npy cube has no wavelength axis; give --wavelengths FILE (one per line) "
                                 "or use .npz with a wavelength_nm array")
            lam = np.loadtxt(wavelengths, ndmin=1)
        elif ext == ".npz":
            z = np.load(p, allow_pickle=False)
            lam, data = _named({k: z[k] for k in z.files}, what)
        elif ext in (".h5", ".hdf5", ".he5"):
            h5py = _optional("h5py", what)
            f = h5py.File(p, "r")
            arrays = {}
            f.visititems(lambda name, obj: arrays.setdefault(name.split("/")[-1], obj)
                         if isinstance(obj, h5py.Dataset) else None)
            lam, data = _named(arrays, what)
        elif ext == ".zarr":
            zarr = _optional("zarr", what)
            g = zarr.open(str(p), mode="r")
            arrays = {k: v for k, v in g.arrays()} if hasattr(g, "arrays") else {"data": g}
            lam, data = _named(arrays, what)
        else:
            raise InputError(f"{what}: unknown cube format (expected one of {', '.join(CUBE_SUFFIXES)})")
    except InputError:
        raise
    except (OSError, ValueError) as exc:
        raise InputError(f"{what}: cannot read it ({str(exc).splitlines()[0][:120]})") from None
    lam_nm, used = _check_wavelengths(lam, what, unit)
    axes = _axes(tuple(data.shape), len(lam_nm), what)
    return SpectralCube(lam_nm, data, axes, str(p), used, (str(p), wavelengths, unit))


def _optional(name: str, what: str):
    import importlib

    try:
        return importlib.import_module(name)
    except ImportError:
        raise InputError(f"{what}: reading it needs the {name} package (pip install 'bubblefit[cubes]')") from None
