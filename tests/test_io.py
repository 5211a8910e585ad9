"""One write path for every output (:mod:`bubblefit.io.atomic`) and the output guard.

Nothing lost: a failed write (a writer's exception, a full disk, an image writer that
reports an error) leaves the earlier file byte-identical and no temporary file; devices
and FIFOs are written in place, never renamed over; links stay links; an output that is
one of the inputs is refused before any work (:func:`bubblefit.cli.common.guard_outputs`).
The full-disk cases run on a 64 KiB tmpfs, mounted where the test may (root), skipped
with the reason otherwise.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest

from bubblefit.errors import InputError, OutputError
from bubblefit.io.atomic import atomic_path, json_text, write_json, write_text


def _hidden(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def test_replaces_and_keeps_permissions(tmp_path):
    target = tmp_path / "r.json"
    target.write_text("old")
    os.chmod(target, 0o640)
    write_json(target, {"a": np.float32(1.5), "b": np.arange(3), "c": float("nan")})
    assert json.loads(target.read_text().replace("NaN", "null")) == {"a": 1.5, "b": [0, 1, 2], "c": None}
    assert stat.S_IMODE(target.stat().st_mode) == 0o640
    assert _hidden(tmp_path) == []


def test_failed_writer_leaves_earlier_file(tmp_path):
    target = tmp_path / "out.csv"
    target.write_bytes(b"earlier result\n")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            Path(tmp).write_text("half a tab")
            raise RuntimeError("the writer crashed")
    assert target.read_bytes() == b"earlier result\n"
    assert _hidden(tmp_path) == []
    # an OSError of the writer is one line naming the target, not the temporary file
    with pytest.raises(OutputError, match=r"cannot write .*out\.csv: permission denied"):
        with atomic_path(target):
            raise PermissionError(13, "Permission denied")
    assert target.read_bytes() == b"earlier result\n"


def test_unserialisable_value_writes_nothing(tmp_path):
    target = tmp_path / "r.json"
    target.write_text("{}")
    with pytest.raises(TypeError):
        write_json(target, {"x": object()})
    assert target.read_text() == "{}" and _hidden(tmp_path) == []


def test_missing_folder_and_folder_target(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        write_text(tmp_path / "nope" / "a.txt", "x")
    (tmp_path / "d").mkdir()
    with pytest.raises(OutputError, match="is a folder"):
        write_text(tmp_path / "d", "x")
    assert issubclass(OutputError, InputError)  # exit status 2, one line, like any bad input


def test_symlink_stays_a_link(tmp_path):
    real = tmp_path / "real.txt"
    real.write_text("old")
    link = tmp_path / "link.txt"
    link.symlink_to(real)
    write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"


def test_devices_and_fifos_are_written_in_place(tmp_path):
    """``--json /dev/null`` must not replace /dev/null (as root, a rename would)."""
    before = os.stat("/dev/null")
    write_json("/dev/null", {"a": 1})
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev and after.st_ino == before.st_ino
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = {}

    def reader():
        with open(fifo) as fh:
            got["text"] = fh.read()

    t = threading.Thread(target=reader)
    t.start()
    write_json(fifo, {"b": 2})
    t.join(10)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert json.loads(got["text"]) == {"b": 2}


def test_strict_json_text():
    text = json_text({"x": [1.0, float("inf")], "y": float("nan")}, allow_nan=False)
    assert json.loads(text) == {"x": [1.0, None], "y": None}


def test_image_writer_error_is_one_line(tmp_path):
    from bubblefit.io.images import write_image

    target = tmp_path / "out.unknownext"
    with pytest.raises(OutputError, match="cannot write"):
        write_image(target, np.zeros((4, 4, 3)))
    assert not target.exists() and _hidden(tmp_path) == []


# --------------------------------------------------------------------------------------
# a full disk
# --------------------------------------------------------------------------------------
@pytest.fixture
def small_disk(tmp_path):
    """A 64 KiB tmpfs (root only); skipped with the reason where it cannot be mounted."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip() or r.returncode}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def _fill(folder: Path, leave: int = 1024) -> None:
    """Fill the file system of ``folder`` but ``leave`` bytes."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    with open(folder / "filler", "wb") as fh:
        fh.write(b"\0" * max(free - leave, 0))


def test_full_disk_keeps_earlier_files(small_disk):
    from bubblefit.io.images import read_image, write_image

    earlier_img = small_disk / "out.exr"
    write_image(earlier_img, np.full((4, 4, 3), 0.25), bit_depth=32)
    earlier_json = small_disk / "r.json"
    earlier_json.write_text('{"t": 0.97}\n')
    img_bytes, json_bytes = earlier_img.read_bytes(), earlier_json.read_bytes()
    _fill(small_disk)
    rng = np.random.default_rng(0)
    with pytest.raises(OutputError, match=r"out\.exr: no space left on device"):
        write_image(earlier_img, rng.uniform(size=(128, 128, 3)), bit_depth=32)
    with pytest.raises(OutputError, match=r"r\.json: no space left on device"):
        write_json(earlier_json, {"values": rng.uniform(size=4000)})
    with pytest.raises(OutputError, match="no space left on device"):
        write_text(small_disk / "new.csv", "x" * 200_000)
    assert earlier_img.read_bytes() == img_bytes and earlier_json.read_bytes() == json_bytes
    assert np.allclose(read_image(earlier_img).pixels, 0.25)
    assert not (small_disk / "new.csv").exists() and _hidden(small_disk) == []


# --------------------------------------------------------------------------------------
# outputs that are inputs
# --------------------------------------------------------------------------------------
def test_guard_outputs(tmp_path, monkeypatch):
    from bubblefit.cli.common import guard_outputs

    photo = tmp_path / "photo.png"
    photo.write_bytes(b"pixels")
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputError, match="it is the input"):
        guard_outputs([photo], ["./sub/../photo.png"])  # relative, through a folder and back
    link = tmp_path / "alias.png"
    link.symlink_to(photo)
    with pytest.raises(OutputError, match="it is the input"):
        guard_outputs([link], [photo])
    hard = tmp_path / "hard.png"
    os.link(photo, hard)
    with pytest.raises(OutputError, match="it is the input"):
        guard_outputs([photo], [hard])
    with pytest.raises(OutputError, match="twice"):
        guard_outputs([], [tmp_path / "a.csv", "a.csv"])
    guard_outputs([photo, None], [None, tmp_path / "other.png", "/dev/null", "/dev/null"])  # all fine
    assert photo.read_bytes() == b"pixels"


# --------------------------------------------------------------------------------------
# progress: on a terminal only
# --------------------------------------------------------------------------------------
class _Stream:
    def __init__(self, tty: bool):
        self.tty, self.text = tty, ""

    def isatty(self):
        return self.tty

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_stages_show_on_a_terminal_only(monkeypatch):
    from bubblefit import progress

    monkeypatch.delenv("BUBBLEFIT_VERBOSE", raising=False)
    monkeypatch.delenv("BUBBLEFIT_QUIET", raising=False)
    term, pipe = _Stream(True), _Stream(False)
    for stream in (term, pipe):
        with progress.stage("global search", stream=stream):
            with progress.stage("inner", stream=stream):
                import time

                time.sleep(0.06)
        with pytest.raises(ValueError):
            with progress.stage("refinement", stream=stream):
                raise ValueError("solver failed")
    assert pipe.text == ""
    lines = term.text.splitlines()
    assert lines[0].endswith("global search ...") and lines[1].endswith("  inner ...")
    assert any("inner done in" in ln for ln in lines) and any("refinement failed after" in ln for ln in lines)
    assert all(ln.startswith("[") and " s] " in ln for ln in lines)  # elapsed time on every line
    monkeypatch.setenv("BUBBLEFIT_QUIET", "1")
    quiet = _Stream(True)
    with progress.stage("x", stream=quiet):
        pass
    progress.Progress(3, "frames", stream=quiet).update()
    assert quiet.text == ""


# --------------------------------------------------------------------------------------
# reading: alpha, sizes from the header, paths
# --------------------------------------------------------------------------------------
def _png(width: int, height: int, rows: bytes, colour_type: int = 2) -> bytes:
    """A PNG file written by hand (ISO/IEC 15948): signature, IHDR, one IDAT, IEND."""
    import struct
    import zlib

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b"")


def test_rgba_colour_is_read_as_stored_with_a_warning(tmp_path):
    """A PNG's colour is unassociated (PNG spec, sec. 12.8): with alpha 200 the RGB codes
    are read as stored, not multiplied by 200/255, and a warning says alpha is ignored."""
    from bubblefit.io.images import ImageWarning, read_image, srgb_decode

    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    rgba = np.concatenate([rgb, np.full((6, 5, 1), 200, np.uint8)], axis=2)
    rows = b"".join(b"\0" + row.tobytes() for row in rgba)
    path = tmp_path / "rgba.png"
    path.write_bytes(_png(5, 6, rows, colour_type=6))
    with pytest.warns(ImageWarning, match="alpha"):
        img = read_image(path)
    np.testing.assert_allclose(img.pixels, srgb_decode(rgb / 255.0), rtol=0, atol=1e-12)
    opaque = np.concatenate([rgb, np.full((6, 5, 1), 255, np.uint8)], axis=2)
    path.write_bytes(_png(5, 6, b"".join(b"\0" + row.tobytes() for row in opaque), colour_type=6))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an opaque alpha says nothing
        np.testing.assert_allclose(read_image(path).pixels, srgb_decode(rgb / 255.0), rtol=0, atol=1e-12)


def test_size_is_checked_from_the_header_before_decoding(tmp_path, monkeypatch):
    """A PNG larger than the pixel limit is refused from its header, in one line that names
    the flag raising the limit, before decoding (time and memory stay small); a
    30000x30000 PNG (22 GB as float64) is refused the same way; a raised limit reads it."""
    import time
    import tracemalloc

    from bubblefit.io.images import MAX_PIXELS, read_image

    side = 2000
    rows = b"".join(b"\0" + bytes(3 * side) for _ in range(side))
    path = tmp_path / "big.png"
    path.write_bytes(_png(side, side, rows))
    before = path.read_bytes()
    monkeypatch.setenv("BUBBLEFIT_MAX_PIXELS", "1000000")
    tracemalloc.start()
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="4 megapixels") as err:
        read_image(path)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert time.perf_counter() - t0 < 2 and peak < 5e6 and "--max-megapixels" in str(err.value)
    assert path.read_bytes() == before
    monkeypatch.setenv("BUBBLEFIT_MAX_PIXELS", "5000000")
    assert read_image(path).pixels.shape == (side, side, 3)
    monkeypatch.delenv("BUBBLEFIT_MAX_PIXELS")

    huge = tmp_path / "huge.png"
    huge.write_bytes(_png(30000, 30000, bytes(3000)))
    assert 30000 * 30000 > MAX_PIXELS
    t0 = time.perf_counter()
    with pytest.raises(InputError):
        read_image(huge)
    assert time.perf_counter() - t0 < 2


def test_a_path_that_is_not_utf8_is_one_line(tmp_path):
    from bubblefit.io.images import read_image, write_image

    folder = os.fsdecode(os.fsencode(str(tmp_path)) + b"/caf\xe9")
    os.mkdir(folder)
    path = folder + "/a.png"
    write_image(tmp_path / "a.png", np.full((4, 4, 3), 0.5))
    os.rename(tmp_path / "a.png", path)
    with pytest.raises(InputError, match="not UTF-8"):
        read_image(path)


def test_tiff_is_written_and_read_back(tmp_path):
    """TIFF output (8 and 16 bit) reads back within a code value."""
    from bubblefit.io.images import read_image, srgb_decode, srgb_encode, write_image

    img = np.linspace(0.0, 1.0, 4 * 6 * 3).reshape(4, 6, 3)
    for depth, maxcode in ((8, 255), (16, 65535)):
        write_image(tmp_path / "a.tif", img, bit_depth=depth)
        got = read_image(tmp_path / "a.tif")
        assert got.bit_depth == depth
        want = srgb_decode(np.round(srgb_encode(img) * maxcode) / maxcode)
        np.testing.assert_allclose(got.pixels, want, atol=1e-6)


def test_an_8bit_environment_map_is_warned_about(tmp_path):
    """A JPEG map is read, with a warning that it is 8-bit and clipped; an EXR map is not."""
    import warnings

    from bubblefit.cli.fit import load_envmap
    from bubblefit.io.images import ImageWarning, write_image

    px = np.full((16, 32, 3), 0.4)
    px[3, 5] = 50.0  # a sun, clipped to 1 in the JPEG
    write_image(tmp_path / "env.jpg", px)
    write_image(tmp_path / "env.exr", px, bit_depth=32)
    with pytest.warns(ImageWarning, match="8 bits per channel"):
        env = load_envmap(str(tmp_path / "env.jpg"))
    assert float(np.max(env.pixels)) <= 1.0 + 1e-6
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImageWarning)
        assert float(np.max(load_envmap(str(tmp_path / "env.exr")).pixels)) > 10
