"""Hypothesis fuzz over the headers of image files: whatever the header says, reading the
file ends in an image of finite pixels or in one :class:`~bubblefit.errors.InputError`,
never in another exception (an internal error), and never decodes more pixels than the
limit allows.

Each case starts from a small valid file of one format (PNG, JPEG, TIFF, EXR) written by
OpenImageIO and replaces bytes in its first 512 bytes (where every format keeps its
header: sizes, channel counts, compression, offsets), or cuts the file short. The pixel
limit is lowered to one million for the run, so that a header mutated into a huge size is
refused before decoding (and a shared test machine is never asked for gigabytes).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

FORMATS = ("png", "jpg", "tif", "exr")
HEADER_BYTES = 512
LIMIT_PIXELS = 1_000_000


@pytest.fixture(scope="module")
def originals(tmp_path_factory) -> dict[str, bytes]:
    """The valid file of each format (24x32 RGB, a smooth gradient and noise)."""
    import OpenImageIO as oiio

    d = tmp_path_factory.mktemp("fuzz_src")
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:24, 0:32]
    img = np.stack([xx / 32, yy / 24, 0.5 + 0.1 * rng.standard_normal((24, 32))], axis=2).clip(0, 1)
    out = {}
    for ext in FORMATS:
        path = d / f"src.{ext}"
        float_file = ext == "exr"
        spec = oiio.ImageSpec(32, 24, 3, oiio.HALF if float_file else oiio.UINT8)
        if ext == "tif":
            spec.attribute("tiff:write_exif", 0)
        w = oiio.ImageOutput.create(str(path))
        assert w.open(str(path), spec)
        assert w.write_image(img.astype(np.float32) if float_file else np.round(img * 255).astype(np.uint8))
        assert w.close()
        out[ext] = path.read_bytes()
    return out


EDITS = st.lists(st.tuples(st.integers(0, HEADER_BYTES - 1), st.integers(0, 255)), min_size=1, max_size=8)


@settings(max_examples=200, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(ext=st.sampled_from(FORMATS), edits=EDITS, cut=st.one_of(st.none(), st.floats(0.0, 1.0)))
def test_mutated_headers_never_cause_an_internal_error(ext, edits, cut, originals, tmp_path_factory, monkeypatch):
    from bubblefit.errors import InputError
    from bubblefit.io.images import read_image

    monkeypatch.setenv("BUBBLEFIT_MAX_PIXELS", str(LIMIT_PIXELS))
    data = bytearray(originals[ext])
    for pos, value in edits:
        if pos < len(data):
            data[pos] = value
    if cut is not None:
        data = data[: int(len(data) * cut)]
    path = tmp_path_factory.mktemp("fuzz") / f"mutated.{ext}"
    path.write_bytes(bytes(data))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            img = read_image(path)
    except InputError as exc:
        assert str(exc) and "\n" not in str(exc).strip()
        return
    h, w, c = img.pixels.shape
    assert c == 3 and h * w <= LIMIT_PIXELS and np.all(np.isfinite(img.pixels))
    assert path.read_bytes() == bytes(data)  # reading never changes the input


@pytest.mark.parametrize("ext", FORMATS)
def test_every_cut_of_a_file_is_refused_or_read_right(ext, originals, tmp_path):
    """A file cut anywhere is refused, or (where the cut takes only bytes after the pixels,
    as in a TIFF whose tail holds its tags' values) read with exactly the pixels of the whole
    file: never read with rows filled in by the decoder."""
    from bubblefit.errors import InputError
    from bubblefit.io.images import read_image

    whole = tmp_path / f"whole.{ext}"
    whole.write_bytes(originals[ext])
    want = read_image(whole).pixels
    data = originals[ext]
    accepted = 0
    for cut in np.unique(np.linspace(1, len(data) - 1, 40).astype(int)):
        part = tmp_path / f"cut.{ext}"
        part.write_bytes(data[:cut])
        try:
            got = read_image(part).pixels
        except InputError:
            continue
        accepted += 1
        np.testing.assert_array_equal(got, want, err_msg=f"{ext} cut at {cut} of {len(data)} bytes")
    # most cuts take pixels; a TIFF keeps its tags' values after the pixels, so a few cuts of
    # its tail leave every pixel (and are read right, as checked above)
    assert accepted <= (10 if ext == "tif" else 2)
