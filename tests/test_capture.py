"""Tests of bubblefit.capture.protocols (protocol specs and checks) and ``bubblefit check-capture``.

Each protocol gets a good synthetic capture that must pass and bad ones, one fault each,
that must fail on the right check with the right reason.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import OpenImageIO as oiio
import pytest

from bubblefit.capture import measure, protocols
from bubblefit.lighting import envmap as em
from bubblefit.errors import BubblefitError, InputError
from bubblefit.io.images import read_image, srgb_encode
from bubblefit.capture.ball import Circle
from bubblefit.capture.probe import mirror_ball_directions

META = {"ExposureTime": 1 / 60, "FNumber": 8.0, "Exif:ISOSpeedRatings": 100, "Exif:WhiteBalance": 1,
        "Exif:FocalLength": 50.0}


def write(path: Path, linear: np.ndarray, bits: int = 16, **meta) -> None:
    """Write a linear image as an sRGB-encoded PNG with EXIF attributes (None drops one)."""
    attrs = {**META, **meta}
    maxcode = 255 if bits == 8 else 65535
    codes = np.round(srgb_encode(np.clip(linear, 0, 1)) * maxcode).astype(np.uint8 if bits == 8 else np.uint16)
    spec = oiio.ImageSpec(codes.shape[1], codes.shape[0], 3, oiio.UINT8 if bits == 8 else oiio.UINT16)
    for k, v in attrs.items():
        if v is not None:
            spec.attribute(k, v)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(codes))
    out.close()


# ------------------------------------------------------------------------------ specs


def test_protocol_specs_load_and_name_their_documents():
    names = protocols.list_protocols()
    assert {"transmission", "envmap", "bubble"} <= set(names)
    for name in names:
        spec = protocols.load_protocol(name)
        assert spec["name"] == name
        doc = protocols.protocols_dir() / spec["document"]
        assert doc.is_file(), doc
        text = doc.read_text()
        # the document lists every file role and the checks of its spec
        for role in spec["files"]:
            for pattern in role["patterns"]:
                assert pattern.split("*")[0] in text, (name, pattern)
    assert (protocols.protocols_dir() / "README.md").is_file()


def test_unknown_protocol_and_bad_folders(tmp_path):
    with pytest.raises(InputError, match="unknown capture protocol"):
        protocols.load_protocol("nonesuch")
    with pytest.raises(InputError, match="not found"):
        protocols.check_capture(tmp_path / "missing", "transmission")
    with pytest.raises(InputError, match="no images"):
        protocols.check_capture(tmp_path, "transmission")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[files\n")
    with pytest.raises(InputError, match="not valid TOML"):
        protocols.load_protocol(bad)


# ------------------------------------------------------------------------------ transmission


def checker(h=96, w=128, sq=8):
    yy, xx = np.mgrid[0:h, 0:w]
    c = ((yy // sq + xx // sq) % 2).astype(float)
    img = 0.04 + 0.5 * c
    return np.stack([img * 0.9, img, img * 0.8], axis=-1)


def with_bubble(bg, cx=64, cy=48, r=22, t4=0.89, highlight=0.0):
    h, w = bg.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    d = np.hypot(xx + 0.5 - cx, yy + 0.5 - cy)
    inside = d < r
    out = bg.copy()
    out[inside] *= t4
    out[inside] += 0.03 * (d[inside] / r)[:, None] ** 4  # brighter rim reflection
    if highlight:
        spot = np.hypot(xx + 0.5 - cx + r / 3, yy + 0.5 - cy + r / 3) < 3
        out[spot] = highlight
    return out


def make_transmission(folder: Path, fault: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    before = checker()
    after = with_bubble(before, highlight=2.0 if fault == "saturated" else 0.0)
    meta_after = {}
    if fault == "shifted":
        after = np.roll(after, (0, 6), axis=(0, 1))
    if fault == "size":
        after = after[:, :120]
    if fault == "exposure_meta":
        meta_after["ExposureTime"] = 1 / 30
    if fault == "exposure_pixels":
        after = after * 1.4
    if fault == "white_balance_pixels":
        after = after * [1.12, 1.0, 0.88]
    if fault == "white_balance_auto":
        meta_after["Exif:WhiteBalance"] = 0
    if fault == "no_bubble":
        after = before.copy()
    write(folder / "before.png", before)
    if fault != "missing":
        write(folder / "after.png", after, **meta_after)
    return folder


def test_transmission_good_capture_passes(tmp_path):
    rep = protocols.check_capture(make_transmission(tmp_path / "good"), "transmission")
    table = protocols.format_table(rep)
    print(table)
    assert rep.passed, table
    status = {r.check: r.status for r in rep.results}
    for check in ("files", "same_size", "locked", "white_balance", "photometric", "registration", "subject", "saturation"):
        assert status[check] == "PASS", table
    x, y, w, h = rep.measurements["bubble_bbox_px"]
    assert abs(x + w / 2 - 64) <= 2 and abs(w - 44) <= 4


@pytest.mark.parametrize(
    "fault, check, reason",
    [
        ("missing", "files", "missing 'after'"),
        ("size", "same_size", "differ in size"),
        ("exposure_meta", "locked", "exposure_time differs"),
        ("exposure_pixels", "photometric", "exposure changed"),
        ("white_balance_pixels", "photometric", "white balance changed"),
        ("white_balance_auto", "white_balance", "auto white balance"),
        ("shifted", "registration", "shifted by (+"),
        ("saturated", "saturation", "saturated pixel(s) inside the bubble in after.png"),
        ("no_bubble", "subject", "no bubble found"),
    ],
)
def test_transmission_bad_capture_fails_with_reason(tmp_path, fault, check, reason):
    rep = protocols.check_capture(make_transmission(tmp_path / fault, fault), "transmission")
    table = protocols.format_table(rep)
    assert not rep.passed, table
    failed = {r.check: r.reason for r in rep.failed()}
    assert check in failed, table
    assert reason in failed[check], table
    # one fault, one failed check (auto white balance also differs from the manual one)
    assert set(failed) <= {check, "locked"} if fault == "white_balance_auto" else set(failed) == {check}, table
    if fault == "shifted":
        (dx, dy), = rep.measurements["shift_px"].values()
        assert abs(dx - 6) < 0.3 and abs(dy) < 0.3


# ------------------------------------------------------------------------------ envmap


def ball_image(size=128, circle=Circle(64, 64, 48), scale=1.0, bg=0.02):
    env = np.ones((16, 32, 3)) * [0.5, 0.55, 0.6]
    env[:8] = [2.0, 2.4, 3.0]  # sky
    env[3, 20] = [400.0, 380.0, 350.0]  # sun
    dirs, inside = mirror_ball_directions((size, size), circle)
    L = np.asarray(jax.jit(em.lookup)(jnp.asarray(env), jnp.asarray(np.where(inside[..., None], dirs, [0, 1.0, 0]))))
    return np.where(inside[..., None], L, bg) * scale


def make_envmap(folder: Path, fault: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    times = [1 / 8, 1 / 32, 1 / 128, 1 / 512, 1 / 2048]
    if fault == "narrow":
        times = [1 / 8, 1 / 16, 1 / 32]
    scale = 40.0 if fault == "sun_clipped" else 1.0
    circle = Circle(64, 64, 20) if fault == "small" else Circle(64, 64, 48)
    img = ball_image(circle=circle, scale=scale)
    for k, t in enumerate(times):
        x = img
        meta = {"ExposureTime": t}
        if fault == "moved" and k == 2:
            x = ball_image(circle=Circle(70, 64, 48))
        if fault == "white_balance" and k == 1:
            meta["Exif:WhiteBalance"] = 0
        if fault == "no_time":
            meta["ExposureTime"] = None
        write(folder / f"probe_{k}.png", x * t, **meta)
    return folder


def test_envmap_good_capture_passes(tmp_path):
    rep = protocols.check_capture(make_envmap(tmp_path / "good"), "envmap")
    table = protocols.format_table(rep)
    print(table)
    assert rep.passed, table
    assert rep.measurements["bracket_stops"] == pytest.approx(8.0)
    assert abs(rep.measurements["ball"]["r"] - 48) < 1.0


@pytest.mark.parametrize(
    "fault, check, reason",
    [
        ("narrow", "brackets", "span 2.0 stops"),
        ("sun_clipped", "saturation", "saturated pixel(s) inside the ball"),
        ("white_balance", "white_balance", "auto white balance in probe_1.png"),
        ("moved", "registration", "shifted by"),
        ("small", "subject", "radius is 20 px"),
        ("no_time", "metadata", "exposure_time"),
    ],
)
def test_envmap_bad_capture_fails_with_reason(tmp_path, fault, check, reason):
    rep = protocols.check_capture(make_envmap(tmp_path / fault, fault), "envmap")
    table = protocols.format_table(rep)
    failed = {r.check: r.reason for r in rep.failed()}
    assert check in failed, table
    assert reason in failed[check], table


# ------------------------------------------------------------------------------ bubble


def test_bubble_protocol(tmp_path):
    good = tmp_path / "good"
    good.mkdir()
    bg = checker() * 0.8
    write(good / "background.png", bg)
    write(good / "bubble_001.png", with_bubble(bg, t4=0.9))
    write(good / "bubble_002.png", with_bubble(bg, t4=0.9, cx=60))
    rep = protocols.check_capture(good, "bubble")
    assert rep.passed, protocols.format_table(rep)
    assert sum(r.check == "subject" and r.status == "PASS" for r in rep.results) == 2


def test_bubble_protocol_accepts_the_readme_names(tmp_path):
    """The README's names: bubble.png and empty.png (empty* is the background frame)."""
    bg = checker() * 0.8
    write(tmp_path / "empty.png", bg)
    write(tmp_path / "bubble.png", with_bubble(bg, t4=0.9))
    rep = protocols.check_capture(tmp_path, "bubble")
    assert rep.passed, protocols.format_table(rep)
    assert rep.files == {"background": ["empty.png"], "bubble": ["bubble.png"]}


def test_bubble_protocol_fails_without_a_background_frame(tmp_path):
    write(tmp_path / "bubble.png", with_bubble(checker() * 0.8, t4=0.9))
    rep = protocols.check_capture(tmp_path, "bubble")
    assert not rep.passed
    failed = {r.check: r.reason for r in rep.failed()}
    assert "files" in failed and "missing 'background'" in failed["files"], protocols.format_table(rep)
    assert "empty*" in failed["files"]


CAPTURE = Path(__file__).parent / "data" / "capture"


def test_bubble_protocol_invents_no_shift_on_a_mitsuba_capture(tmp_path):
    """A Mitsuba 3 render of a bubble filling a third of the frame and the same view without
    it, renamed as the README says: the camera did not move, and no shift may be reported
    (phase correlation alone put its peak at (+18, -40) px)."""
    (tmp_path / "empty.png").write_bytes((CAPTURE / "mitsuba_empty.png").read_bytes())
    (tmp_path / "bubble.png").write_bytes((CAPTURE / "mitsuba_bubble.png").read_bytes())
    rep = protocols.check_capture(tmp_path, "bubble")
    table = protocols.format_table(rep)
    print(table)
    status = {r.check: (r.status, r.reason) for r in rep.results}
    assert status["registration"][0] == "PASS", table
    assert rep.measurements["shift_px"]["empty.png->bubble.png"] == [0.0, 0.0]
    assert status["subject"][0] == "PASS", table
    assert status["photometric"][0] == "PASS", table


def test_bubble_protocol_names_a_different_scene_not_a_shift(tmp_path):
    """Frames of two different scenes: no made-up shift, a reason a person can act on."""
    (tmp_path / "empty.png").write_bytes((CAPTURE / "mitsuba_other_empty.png").read_bytes())
    other = read_image(CAPTURE / "mitsuba_other_empty.png").pixels
    bub = read_image(CAPTURE / "mitsuba_bubble.png").pixels[:other.shape[0], :other.shape[1]]
    bub = np.pad(bub, ((0, other.shape[0] - bub.shape[0]), (0, other.shape[1] - bub.shape[1]), (0, 0)), mode="edge")
    write(tmp_path / "bubble.png", bub, bits=8, ExposureTime=None, FNumber=None)
    rep = protocols.check_capture(tmp_path, "bubble")
    table = protocols.format_table(rep)
    reg = next(r for r in rep.results if r.check == "registration")
    assert reg.status in ("FAIL", "WARN"), table
    assert "shifted by" not in reg.reason and "no camera shift explains it" in reg.reason, table


def test_registration_reports_a_real_shift_only(tmp_path):
    """measure_shift: a 5-px camera move of a textured scene with a bubble in the second
    frame is measured; the same frames unmoved give (0, 0); a bubble alone moves nothing."""
    rng = np.random.default_rng(4)
    tex = cv2.GaussianBlur(rng.random((140, 180, 3)).astype(np.float32), (0, 0), 2.0).astype(np.float64)
    scene = 0.1 + 0.8 * (tex - tex.min()) / (tex.max() - tex.min())
    a = scene[10:106, 10:138]
    b_still = with_bubble(a, cx=60, cy=50, r=30, t4=0.88)
    b_moved = with_bubble(scene[10:106, 15:143], cx=60, cy=50, r=30, t4=0.88)  # camera 5 px to the right
    still = measure.measure_shift(a, b_still)
    assert still.clear and (still.dx, still.dy) == (0.0, 0.0)
    moved = measure.measure_shift(a, b_moved)
    assert moved.clear and abs(moved.dx + 5) < 0.3 and abs(moved.dy) < 0.3, moved


# ------------------------------------------------------------------------------ CLI


def cli(argv) -> int:
    from bubblefit.cli import check_capture

    parser = argparse.ArgumentParser(prog="bubblefit")
    sub = parser.add_subparsers(dest="command")
    check_capture.register(sub)
    args = parser.parse_args([str(a) for a in argv])
    try:
        return int(args.func(args) or 0)
    except BubblefitError as exc:
        print(f"bubblefit: error: {exc}")
        return exc.exit_code


def test_cli_check_capture(tmp_path, capsys):
    good = make_transmission(tmp_path / "good")
    js = tmp_path / "report.json"
    assert cli(["check-capture", good, "--protocol", "transmission", "--json", js]) == 0
    out = capsys.readouterr().out
    assert "registration" in out and "PASS" in out.splitlines()[-1]
    assert json.loads(js.read_text())["passed"] is True

    bad = make_transmission(tmp_path / "bad", "shifted")
    assert cli(["check-capture", bad, "--protocol", "transmission"]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "camera moved" in out

    assert cli(["check-capture", tmp_path / "nope", "--protocol", "transmission"]) == 2
    assert "capture folder not found" in capsys.readouterr().out
    assert cli(["check-capture", good, "--protocol", "nonesuch"]) == 2
    empty = tmp_path / "empty"
    empty.mkdir()
    assert cli(["check-capture", empty, "--protocol", "envmap"]) == 2
    assert "no images" in capsys.readouterr().out
