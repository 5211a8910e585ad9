"""Bad input to every command gives one clear line on stderr and a non-zero exit.

docs/design.md, "Command line": a bad input exits non-zero with one clear line on stderr (no
traceback), and outputs are written atomically (temporary file, then rename), so a failed
run leaves neither a half-written file nor a damaged existing one.

Every case calls :func:`bubblefit.cli.main` in-process and reads stderr with ``capsys``.
A hypothesis fuzz test feeds mutated PNG/EXR bytes and mutated TOML scenes to the
``render``, ``envmap`` and ``calibrate`` entry points.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bubblefit import cli
from bubblefit.cli import main
from bubblefit.io.images import write_image

REGISTERED = {name.replace("_", "-") for name in cli.COMMANDS}


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------
def run_cli(capsys, argv) -> tuple[int, str, str]:
    """Run ``bubblefit argv`` in-process: (exit status, stdout, stderr)."""
    capsys.readouterr()
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        rc = exc.code if isinstance(exc.code, int) else 1
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line_error(rc: int, err: str, *, internal_ok: bool = False) -> str:
    """A non-zero exit and exactly one line on stderr, ``bubblefit: error: ...``."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc != 0, f"exit 0 on bad input; stderr: {err!r}"
    assert "Traceback" not in err, err
    assert len(lines) == 1, f"expected one line on stderr, got {len(lines)}: {err!r}"
    prefixes = ("bubblefit: error:",) + (("bubblefit: internal error:",) if internal_ok else ())
    assert lines[0].startswith(prefixes), lines[0]
    assert len(lines[0]) > len("bubblefit: error: ") + 5, "the message says nothing"
    return lines[0]


def assert_no_temp_files(folder: Path) -> None:
    """``atomic_path`` temporaries are hidden files ``.<stem>.<random><ext>``."""
    left = [p.name for p in folder.iterdir() if p.name.startswith(".")]
    assert not left, f"temporary files left behind: {left}"


def need(command: str):
    assert command in REGISTERED, f"command {command} is not registered"


def _disc_photo(h=24, w=24, inside=0.6, outside=0.3, seed=0):
    """A small linear photo: a flat background and a brighter disc (a stand-in bubble)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5
    disc = (xx - w / 2) ** 2 + (yy - h / 2) ** 2 < (0.35 * min(h, w)) ** 2
    img = np.where(disc[..., None], inside, outside) * np.ones((h, w, 3))
    return np.clip(img + rng.normal(0, 0.01, img.shape), 0, 1)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Good and bad input files shared by the cases (all tiny)."""
    d = tmp_path_factory.mktemp("cli_inputs")
    f = {}
    rng = np.random.default_rng(1)
    env = rng.uniform(0.05, 1.0, (16, 32, 3))
    env[3, 5] = 30000.0  # a sun texel
    f["env"] = d / "env.exr"
    write_image(f["env"], env, bit_depth=32)
    f["env_not_2to1"] = d / "env_square.exr"
    write_image(f["env_not_2to1"], env[:, :16], bit_depth=32)
    f["env_tiny"] = d / "env_tiny.exr"
    write_image(f["env_tiny"], np.ones((1, 2, 3)), bit_depth=32)
    nan = env.copy()
    nan[2, 2] = np.nan
    nan[4, 4] = np.inf
    f["env_nan"] = d / "env_nan.exr"
    write_image(f["env_nan"], nan, bit_depth=32)
    negative = env.copy()
    negative[5, 7] = -5.0  # ten times the typical radiance: no ringing of a real map
    f["env_negative"] = d / "env_negative.exr"
    write_image(f["env_negative"], negative, bit_depth=32)
    photo = _disc_photo()
    f["photo"] = d / "photo.png"
    write_image(f["photo"], photo)
    f["photo_other_size"] = d / "photo_small.png"
    write_image(f["photo_other_size"], _disc_photo(16, 20))
    f["photo16"] = d / "photo16.png"
    write_image(f["photo16"], photo, bit_depth=16)
    f["photo_float"] = d / "photo_float.exr"
    write_image(f["photo_float"], photo, bit_depth=32)
    f["gray"] = d / "gray.png"
    write_image(f["gray"], photo[..., :1])
    f["rgba"] = d / "rgba.png"
    write_image(f["rgba"], np.concatenate([photo, np.ones_like(photo[..., :1])], axis=2))
    f["black"] = d / "black.png"
    write_image(f["black"], np.zeros_like(photo))
    f["white"] = d / "white.png"
    write_image(f["white"], np.ones_like(photo))
    raw = f["photo"].read_bytes()
    f["truncated"] = d / "truncated.png"
    f["truncated"].write_bytes(raw[: len(raw) // 2])
    f["empty"] = d / "empty.png"
    f["empty"].write_bytes(b"")
    f["garbage"] = d / "garbage.png"
    f["garbage"].write_bytes(rng.integers(0, 256, 600, dtype=np.uint8).tobytes())
    f["text_as_exr"] = d / "text.exr"
    f["text_as_exr"].write_text("this is not an image\n")
    f["missing"] = d / "does_not_exist.png"
    f["folder"] = d / "a_folder"
    f["folder"].mkdir()
    f["empty_dir"] = d / "empty_dir"
    f["empty_dir"].mkdir()
    f["no_dir_out"] = d / "no_such_dir" / "out.exr"
    return f


def scene_text(env: Path | None, extra: str = "", *, width=8, height=8) -> str:
    lighting = f'[lighting]\nenvmap = "{env}"\n' if env is not None else '[lighting]\nbackground = "black"\n'
    return (f"[camera]\nwidth = {width}\nheight = {height}\n\n[bubble]\nthickness_nm = 400.0\nroughness = 0.05\n\n"
            f"{lighting}\n[effects]\nfiltering = \"mirror\"\ninterference = \"off\"\n{extra}")


def write_scene(folder: Path, name: str, text: str) -> Path:
    p = folder / name
    p.write_text(text)
    return p


# --------------------------------------------------------------------------------------
# bad input, command by command
# --------------------------------------------------------------------------------------
SCENE_CASES = {
    "unknown_table": "[nonsense]\nx = 1\n",
    "unknown_key": "[bubble]\nthicknes_nm = 300.0\n",
    "wrong_type": '[bubble]\nt = "high"\n',
    "bool_for_float": "[bubble]\nroughness = true\n",
    "out_of_range_t": "[bubble]\nt = 1.5\n",
    "negative_roughness": "[bubble]\nroughness = -0.1\n",
    "nan_value": "[bubble]\nt = nan\n",
    "inf_radius": "[bubble]\nradius = inf\n",
    "zero_width": "[camera]\nwidth = 0\n",
    "bad_camera_type": '[camera]\ntype = "fisheye"\n',
    "bad_disc": "[camera]\ndisc = [1, 2]\n",
    "disc_strings": '[camera]\ndisc = ["a", "b", "c"]\n',
    "bad_model": '[effects]\nmodel = "magic"\n',
    "bad_interference": '[effects]\ninterference = "three_beam"\n',
    "bad_filtering": '[effects]\nfiltering = "bilinear"\n',
    "bad_bool_effect": '[effects]\ndiffuse = "maybe"\n',
    "bad_spectral": '[effects]\nspectral = "rainbow"\n',
    "negative_nodes": "[effects]\nnodes = -3\n",
    "bad_thickness_profile": '[bubble.thickness]\nprofile = "wavy"\n',
    "map_without_path": '[bubble.thickness]\nprofile = "map"\n',
    "map_missing_file": '[bubble.thickness]\nprofile = "map"\npath = "nowhere.exr"\n',
    "bad_point_light": "[lighting]\npoint_lights = [1, 2, 3]\n",
    "zero_light_direction": "[lighting]\npoint_lights = [{direction = [0, 0, 0], radiance = [1, 1, 1]}]\n",
    "light_radiance_strings": '[lighting]\npoint_lights = [{direction = [0, 1, 0], radiance = "bright"}]\n',
    "table_as_value": "camera = 3\n",
    "not_toml": "this is = = not toml [[[\n",
    "binary": "\x00\x01\x02\xff",
    "missing_envmap": '[lighting]\nenvmap = "nowhere.exr"\n',
    # degenerate cameras: refused in one line, before any arithmetic warns
    "fov_zero": '[camera]\ntype = "perspective"\nfov_deg = 0.0\n',
    "fov_180": '[camera]\ntype = "perspective"\nfov_deg = 180.0\n',
    "camera_at_centre": '[camera]\ntype = "perspective"\norigin = [0.0, 0.0, 0.0]\ntarget = [0.0, 0.0, -1.0]\n',
    "up_parallel": '[camera]\ntype = "perspective"\nup = [0.0, 0.0, 1.0]\n',
    "target_is_origin": '[camera]\ntype = "perspective"\norigin = [0.0, 0.0, 4.0]\ntarget = [0.0, 0.0, 4.0]\n',
    "disc_zero_radius": "[camera]\ndisc = [4.0, 4.0, 0.0]\n",
    "missing_background": '[lighting]\nbackground = "nowhere.png"\n',
}


def _compose(base: str, case: str) -> str:
    """Merge a case's tables into the base scene (later keys of the same table win)."""
    if case in ("not_toml", "binary", "table_as_value"):
        return SCENE_CASES[case]
    import tomllib

    base_d = tomllib.loads(base)
    try:
        case_d = tomllib.loads(SCENE_CASES[case])
    except tomllib.TOMLDecodeError:
        return SCENE_CASES[case]
    for k, v in case_d.items():
        if isinstance(v, dict) and isinstance(base_d.get(k), dict):
            base_d[k].update(v)
        else:
            base_d[k] = v
    return _dump_toml(base_d)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v == float("inf") else ("-inf" if v == -float("inf") else repr(v)))
    if isinstance(v, (int,)):
        return str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(v)


def _dump_toml(d: dict) -> str:
    lines = []
    for table, body in d.items():
        if not isinstance(body, dict):
            lines.insert(0, f"{table} = {_toml_value(body)}")
            continue
        sub = {k: v for k, v in body.items() if isinstance(v, dict)}
        lines.append(f"[{table}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in body.items() if not isinstance(v, dict)]
        for k, v in sub.items():
            lines.append(f"[{table}.{k}]")
            lines += [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("case", sorted(SCENE_CASES))
def test_render_bad_scene(case, files, tmp_path, capsys):
    text = _compose(scene_text(files["env"]), case)
    scene = write_scene(tmp_path, "scene.toml", text)
    out = tmp_path / "out.exr"
    out.write_bytes(b"previous result")
    rc, _, err = run_cli(capsys, ["render", scene, "-o", out])
    assert_one_line_error(rc, err)
    assert out.read_bytes() == b"previous result"
    assert not (tmp_path / "out.png").exists()
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("which", ["missing", "truncated", "empty", "garbage", "text_as_exr", "folder",
                                   "env_not_2to1", "env_tiny", "env_nan", "env_negative"])
def test_render_bad_envmap(which, files, tmp_path, capsys):
    scene = write_scene(tmp_path, "scene.toml", scene_text(files[which]))
    rc, _, err = run_cli(capsys, ["render", scene, "-o", tmp_path / "out.exr"])
    line = assert_one_line_error(rc, err)
    assert "environment map" in line or "image" in line or "envmap" in line, line
    assert not (tmp_path / "out.exr").exists()


def test_render_missing_and_folder_scene(files, tmp_path, capsys):
    for path in (files["missing"].with_suffix(".toml"), files["folder"]):
        rc, _, err = run_cli(capsys, ["render", path, "-o", tmp_path / "out.exr"])
        assert_one_line_error(rc, err)


def test_render_unwritable_output_keeps_previous(files, tmp_path, capsys):
    """The render succeeds but the output cannot be written: one line, nothing lost."""
    scene = write_scene(tmp_path, "scene.toml", scene_text(files["env"]))
    for target in (files["no_dir_out"], files["folder"], tmp_path / "out.unknownext"):
        rc, _, err = run_cli(capsys, ["render", scene, "-o", target])
        assert_one_line_error(rc, err)
    assert files["folder"].is_dir() and not any(files["folder"].iterdir())
    prev = tmp_path / "prev.exr"
    prev.write_bytes(b"keep me")
    # --json into a missing folder fails after the image: the image is complete, the
    # JSON is not written, and no temporary file remains.
    rc, _, err = run_cli(capsys, ["render", scene, "-o", prev, "--json", tmp_path / "nope" / "r.json"])
    assert_one_line_error(rc, err)
    assert_no_temp_files(tmp_path)


def test_render_good_scene_still_works(files, tmp_path, capsys):
    """The control: the same helpers accept a good scene (so the cases above can fail)."""
    scene = write_scene(tmp_path, "scene.toml", scene_text(files["env"]))
    out = tmp_path / "out.exr"
    rc, _, err = run_cli(capsys, ["render", scene, "-o", out])
    assert rc == 0, err
    from bubblefit.io.images import read_image

    img = read_image(out).pixels
    assert img.shape == (8, 8, 3) and np.all(np.isfinite(img)) and img.max() > 0
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("argv", [
    ["--thickness", "abc"], ["--thickness", "10:0:5"], ["--thickness", "0:10:0"], ["--thickness", "0:1e9:1e-3"],
    ["--thickness", "nan:10:1"], ["--angle-deg", "120"], ["--angle-deg", "nan"], ["--n-film", "0.5"],
    ["--n-film", "inf"], ["--model", "magic"],
])
def test_chart_bad_arguments(argv, tmp_path, capsys):
    out = tmp_path / "chart.png"
    out.write_bytes(b"old chart")
    rc, _, err = run_cli(capsys, ["chart", *argv, "-o", out])
    assert_one_line_error(rc, err)
    assert out.read_bytes() == b"old chart"
    assert_no_temp_files(tmp_path)


def test_chart_unwritable_outputs(files, tmp_path, capsys):
    for argv in (["-o", files["no_dir_out"].with_suffix(".png")], ["-o", tmp_path / "chart.unknownext"],
                 ["-o", files["folder"]]):
        rc, _, err = run_cli(capsys, ["chart", "--thickness", "0:100:50", *argv])
        assert_one_line_error(rc, err)
    assert_no_temp_files(tmp_path)


CAL_CASES = {
    "missing_before": ("missing", "photo"),
    "missing_after": ("photo", "missing"),
    "truncated": ("photo", "truncated"),
    "empty_file": ("empty", "photo"),
    "garbage": ("photo", "garbage"),
    "folder": ("folder", "photo"),
    "sizes_differ": ("photo", "photo_other_size"),
    "black": ("black", "black"),
    "saturated": ("white", "white"),
    "nan_pixels": ("env_nan", "env_nan"),
}


@pytest.mark.parametrize("case", sorted(CAL_CASES))
def test_calibrate_bad_images(case, files, tmp_path, capsys):
    before, after = CAL_CASES[case]
    out = tmp_path / "cal.json"
    out.write_text('{"t": 0.9}')
    rc, _, err = run_cli(capsys, ["calibrate", files[before], files[after], "--json", out, "--bootstrap", "100", "-q"])
    assert_one_line_error(rc, err)
    assert out.read_text() == '{"t": 0.9}'
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("argv", [["--circle", "1,2"], ["--circle", "1,2,-3"], ["--inner-fraction", "2"],
                                  ["--bootstrap", "3"], ["--circle", "nan,1,1"]])
def test_calibrate_bad_options(argv, files, capsys):
    rc, _, err = run_cli(capsys, ["calibrate", files["photo"], files["photo"], *argv])
    assert_one_line_error(rc, err)


@pytest.mark.parametrize("fmt", ["photo16", "photo_float", "gray", "rgba"])
def test_calibrate_other_formats_never_traceback(fmt, files, tmp_path, capsys):
    """16-bit, float, grayscale and RGBA files are usable input: either a result or one line."""
    rc, _, err = run_cli(capsys, ["calibrate", files["photo"], files[fmt], "--bootstrap", "100", "-q"])
    assert "Traceback" not in err and "internal error" not in err, err
    if rc != 0:
        assert_one_line_error(rc, err)


ENVMAP_CASES = {
    "missing": ["missing"],
    "truncated": ["truncated"],
    "empty": ["empty"],
    "garbage": ["garbage"],
    "folder": ["folder"],
    "nan_pixels": ["env_nan"],
    "sizes_differ": ["photo", "photo_other_size"],
    "black": ["black"],
}


@pytest.mark.parametrize("case", sorted(ENVMAP_CASES))
def test_envmap_bad_probes(case, files, tmp_path, capsys):
    out = tmp_path / "env.exr"
    out.write_bytes(b"old map")
    argv = ["envmap", *[files[k] for k in ENVMAP_CASES[case]], "-o", out, "--height", "8"]
    if case == "sizes_differ":
        argv += ["--times", "1", "0.5"]
    rc, _, err = run_cli(capsys, argv)
    assert_one_line_error(rc, err)
    assert out.read_bytes() == b"old map"
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("argv", [["-o", "out.png"], ["--height", "2"], ["--ball", "1,2"], ["--ball", "5,5,0"],
                                  ["--times", "1", "2"], ["--times", "-1"], ["--ball", "500,500,3"]])
def test_envmap_bad_options(argv, files, tmp_path, capsys):
    if "-o" not in argv:
        argv = [*argv, "-o", tmp_path / "env.exr"]
    else:
        argv = ["-o", tmp_path / argv[1]]
    rc, _, err = run_cli(capsys, ["envmap", files["photo"], *argv])
    assert_one_line_error(rc, err)
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("case", ["missing_dir", "empty_dir", "unknown_protocol", "file_not_dir", "json_unwritable"])
def test_check_capture_bad_input(case, files, tmp_path, capsys):
    folder, protocol, extra = files["empty_dir"], "transmission", []
    if case == "missing_dir":
        folder = files["missing"]
    elif case == "unknown_protocol":
        folder, protocol = files["folder"], "no_such_protocol"
    elif case == "file_not_dir":
        folder = files["photo"]
    elif case == "json_unwritable":
        extra = ["--json", files["no_dir_out"].with_suffix(".json")]
    rc, _, err = run_cli(capsys, ["check-capture", folder, "--protocol", protocol, *extra])
    # an unwritable --json is refused before the checks run (not reported as a failed check)
    assert_one_line_error(rc, err)


FITSEQ_CASES = {
    "missing_frame": (["missing"], "env", []),
    "truncated_frame": (["truncated"], "env", []),
    "garbage_frame": (["garbage"], "env", []),
    "empty_folder": (["empty_dir"], "env", []),
    "envmap_missing": (["photo"], "missing", []),
    "envmap_not_2to1": (["photo"], "env_not_2to1", []),
    "envmap_nan": (["photo"], "env_nan", []),
    "bad_t": (["photo"], "env", ["--t", "1.5"]),
    "bad_set": (["photo"], "env", ["--set", "roughness=-1"]),
    "bad_disc": (["photo"], "env", ["--disc", "1,2"]),
    "bad_range": (["photo"], "env", ["--thickness-range", "a,b"]),
    "bad_calibration": (["photo"], "env", ["--calibration", "garbage"]),
    "bad_scene": (["photo"], "env", ["--scene", "garbage"]),
}


@pytest.mark.parametrize("case", sorted(FITSEQ_CASES))
def test_fit_sequence_bad_input(case, files, tmp_path, capsys):
    need("fit-sequence")
    frames, env, extra = FITSEQ_CASES[case]
    extra = [files[e] if e in files else e for e in extra]
    rc, _, err = run_cli(capsys, ["fit-sequence", *[files[f] for f in frames], "--envmap", files[env],
                                  "-o", tmp_path / "seq", "--workers", "0", "--no-progress", *extra])
    assert_one_line_error(rc, err)


FIT_CASES = {
    "missing_photo": ("missing", "env", []),
    "truncated_photo": ("truncated", "env", []),
    "garbage_photo": ("garbage", "env", []),
    "nan_photo": ("env_nan", "env", []),
    "envmap_missing": ("photo", "missing", []),
    "envmap_not_2to1": ("photo", "env_not_2to1", []),
    "black_photo": ("black", "env", []),
    "saturated_photo": ("white", "env", []),
    "bad_t": ("photo", "env", ["--t", "-1"]),
    "bad_set_name": ("photo", "env", ["--set", "colour=1"]),
    "bad_set_value": ("photo", "env", ["--set", "t=1.5"]),
    "bad_set_form": ("photo", "env", ["--set", "t"]),
    "bad_calibration": ("photo", "env", ["--calibration", "garbage"]),
    "background_other_size": ("photo", "env", ["--background", "photo_other_size"]),
}


@pytest.mark.parametrize("case", sorted(FIT_CASES))
def test_fit_bad_input(case, files, tmp_path, capsys):
    need("fit")
    photo, env, extra = FIT_CASES[case]
    extra = [files[e] if e in files else e for e in extra]
    out = tmp_path / "fit.json"
    out.write_text("{}")
    rc, _, err = run_cli(capsys, ["fit", files[photo], "--envmap", files[env], "--json", out, *extra])
    assert_one_line_error(rc, err)
    assert out.read_text() == "{}"
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("argv", [["--size", "8"], ["--size", "100000"], ["--seed", "x"]])
def test_demo_bad_options(argv, tmp_path, capsys):
    need("demo")
    rc, _, err = run_cli(capsys, ["demo", *argv, "--out", tmp_path / "demo"])
    assert_one_line_error(rc, err)
    assert not (tmp_path / "demo").exists()


@pytest.mark.parametrize("command", sorted(REGISTERED))
def test_usage_errors_are_one_line(command, capsys):
    """Missing arguments, unknown options: argparse's errors are one line too."""
    rc, _, err = run_cli(capsys, [command, "--no-such-option"])
    assert_one_line_error(rc, err)
    rc, out, _ = run_cli(capsys, [command, "--help"])
    assert rc == 0 and "usage" in out.lower()


def test_unexpected_exception_is_one_line(monkeypatch, files, tmp_path, capsys):
    """A bug (any non-bubblefit exception) still gives one line and exit 1, and
    BUBBLEFIT_DEBUG=1 gives the traceback back."""
    import bubblefit.cli.chart as chart_cli

    def boom(args):
        raise ZeroDivisionError("something\nspanning lines")

    monkeypatch.setattr(chart_cli, "run", boom)
    monkeypatch.delenv("BUBBLEFIT_DEBUG", raising=False)
    rc, _, err = run_cli(capsys, ["chart", "-o", tmp_path / "c.png"])
    line = assert_one_line_error(rc, err, internal_ok=True)
    assert rc == 1 and line.startswith("bubblefit: internal error: ZeroDivisionError: something")
    monkeypatch.setenv("BUBBLEFIT_DEBUG", "1")
    with pytest.raises(ZeroDivisionError):
        main(["chart", "-o", str(tmp_path / "c.png")])


# --------------------------------------------------------------------------------------
# fuzzing
# --------------------------------------------------------------------------------------
def _mutate(data: bytes, edits) -> bytes:
    """Apply (kind, position, value) edits: flip a byte, cut the tail, insert, or duplicate a span."""
    b = bytearray(data)
    for kind, pos, val in edits:
        if not b:
            break
        i = pos % len(b)
        if kind == 0:
            b[i] = val
        elif kind == 1:
            del b[i:]
        elif kind == 2:
            b[i:i] = bytes([val]) * (1 + val % 7)
        else:
            b[i:i] = b[i: i + 1 + val]
    return bytes(b)


EDITS = st.lists(st.tuples(st.integers(0, 3), st.integers(0, 1 << 20), st.integers(0, 255)), min_size=1, max_size=6)
_FUZZ = settings(max_examples=30, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _assert_clean(rc, err):
    """A fuzzed input may be accepted; when it is not, one line, never a traceback."""
    assert "Traceback" not in err and "internal error" not in err, err
    if rc != 0:
        assert_one_line_error(rc, err)


@pytest.fixture
def stub_render(monkeypatch):
    """Replace the renderer by a cheap stand-in: the fuzz tests test parsing and error
    handling, not rendering (each new camera would cost a compilation)."""
    import importlib

    render_mod = importlib.import_module("bubblefit.model.render")  # the module, not the function

    def fake_render(params, cfg, env, background=None):
        return np.full((min(cfg.shape[0], 8), min(cfg.shape[1], 8), 3), 0.5)

    monkeypatch.setattr(render_mod, "render", fake_render)


@_FUZZ
@given(edits=EDITS, which=st.sampled_from(["png", "exr"]))
def test_fuzz_images_calibrate_and_envmap(edits, which, files, tmp_path_factory, capsys):
    d = tmp_path_factory.mktemp("fuzz_img")
    src = files["photo"] if which == "png" else files["photo_float"]
    bad = d / f"mutated.{which}"
    bad.write_bytes(_mutate(src.read_bytes(), edits))
    rc, _, err = run_cli(capsys, ["calibrate", files["photo"], bad, "--bootstrap", "100", "-q"])
    _assert_clean(rc, err)
    rc, _, err = run_cli(capsys, ["envmap", bad, "-o", d / "env.exr", "--height", "8"])
    _assert_clean(rc, err)
    assert_no_temp_files(d)


@_FUZZ
@given(edits=EDITS)
def test_fuzz_envmap_exr_in_scene(edits, files, tmp_path_factory, capsys, stub_render):
    d = tmp_path_factory.mktemp("fuzz_env")
    bad = d / "mutated.exr"
    bad.write_bytes(_mutate(files["env"].read_bytes(), edits))
    scene = write_scene(d, "scene.toml", scene_text(bad))
    rc, _, err = run_cli(capsys, ["render", scene, "-o", d / "out.exr"])
    _assert_clean(rc, err)
    assert_no_temp_files(d)


_TOKENS = ["0", "-1", "1e400", "nan", "inf", "true", '"x"', "[]", "[1, 2, 3]", "{}", "1.5", "99999999999",
           '"mirror"', '"physical"', '"map"', "[0, 0, 0]", '{profile = "drainage"}', "-0.0"]


@_FUZZ
@given(text_edits=st.lists(st.tuples(st.integers(0, 10_000), st.sampled_from(_TOKENS)), min_size=1, max_size=4),
       byte_edits=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 1 << 16), st.integers(32, 126)), max_size=3))
def test_fuzz_scene_files(text_edits, byte_edits, files, tmp_path_factory, capsys, stub_render):
    """Mutated scenes: values replaced by odd tokens, then random byte edits."""
    d = tmp_path_factory.mktemp("fuzz_scene")
    base = scene_text(files["env"], '[bubble.thickness]\nprofile = "drainage"\ntop_nm = 100.0\n'
                                    'bottom_nm = 900.0\nexponent = 1.5\n', width=8, height=8)
    base = base.replace("[bubble]\n", "[bubble]\nradius = 1.0\nn_film = 1.4\nt = 0.9\n")
    lines = base.splitlines()
    for pos, token in text_edits:
        value_lines = [i for i, ln in enumerate(lines) if " = " in ln]
        i = value_lines[pos % len(value_lines)]
        lines[i] = lines[i].split(" = ")[0] + " = " + token
    text = _mutate("\n".join(lines).encode(), byte_edits) if byte_edits else "\n".join(lines).encode()
    scene = d / "scene.toml"
    scene.write_bytes(text)
    out = d / "out.exr"
    out.write_bytes(b"previous")
    rc, _, err = run_cli(capsys, ["render", scene, "-o", out])
    _assert_clean(rc, err)
    if rc != 0:
        assert out.read_bytes() == b"previous"
    assert_no_temp_files(d)


# --------------------------------------------------------------------------------------
# nothing lost: outputs that are inputs, full disks, devices, resumes (issue 16)
# --------------------------------------------------------------------------------------
def _snapshot(*paths) -> dict:
    return {str(p): Path(p).read_bytes() for p in paths}


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def _clashes(files, d: Path) -> dict:
    """name -> (argv, the inputs that must stay byte-identical)."""
    env = _copy(files["env"], d / "env.exr")
    photo = _copy(files["photo"], d / "photo.png")
    other = _copy(files["photo"], d / "other.png")
    scene = write_scene(d, "scene.toml", scene_text(env))
    bg_text = scene_text(env).replace("[lighting]\n", '[lighting]\nbackground = "shot.png"\n')
    bg_scene = write_scene(d, "bg_scene.toml", bg_text)
    shot = _copy(files["photo"], d / "shot.png")
    probe = _copy(files["photo"], d / "probe.png")
    fit_photo = _copy(files["photo_float"], d / "P_render.exr")
    ill = d / "ill.csv"
    ill.write_text("wavelength_nm,power\n" + "".join(f"{w},{1 + w / 1000}\n" for w in range(380, 781, 10)))
    resp = d / "resp.csv"
    resp.write_text("wavelength_nm,r,g,b\n" + "".join(f"{w},{max(0, 1 - abs(w - 600) / 80)},"
                                                       f"{max(0, 1 - abs(w - 540) / 80)},"
                                                       f"{max(0, 1 - abs(w - 450) / 80)}\n"
                                                       for w in range(380, 781, 10)))
    return {
        "chart_csv_onto_illuminant": (["chart", "--thickness", "0:100:50", "-o", d / "c.png", "--illuminant", ill,
                                       "--csv", ill], [ill]),
        "fit_json_onto_illuminant": (["fit", photo, "--envmap", env, "--illuminant", ill, "--json", ill],
                                     [photo, env, ill]),
        "fit_json_onto_camera_response": (["fit", photo, "--envmap", env, "--camera-response", resp, "--json", resp],
                                          [photo, env, resp]),
        "fit_sequence_json_onto_illuminant": (["fit-sequence", photo, "--envmap", env, "--disc", "12,12,8",
                                               "--workers", "0", "-o", d / "seq", "--illuminant", ill, "--json", ill,
                                               "--no-progress"], [photo, env, ill]),
        "render_onto_envmap": (["render", scene, "-o", env], [env, scene]),
        "render_preview_onto_background": (["render", bg_scene, "-o", d / "shot.exr"], [shot, bg_scene]),
        "render_json_onto_scene": (["render", scene, "-o", d / "r.exr", "--json", scene], [scene]),
        "fit_prefix_onto_photo": (["fit", fit_photo, "--envmap", env, "-o", d / "P"], [fit_photo, env]),
        "fit_json_onto_envmap": (["fit", photo, "--envmap", env, "--json", env], [photo, env]),
        "calibrate_json_onto_photo": (["calibrate", photo, other, "--json", other], [photo, other]),
        "calibrate_debug_onto_photo": (["calibrate", photo, other, "--debug-image", photo], [photo, other]),
        "envmap_onto_probe_preview": (["envmap", probe, "-o", d / "probe.exr", "--height", "8"], [probe]),
        "envmap_json_onto_probe": (["envmap", probe, "-o", d / "m.exr", "--json", probe], [probe]),
        "chart_csv_is_output": (["chart", "--thickness", "0:100:50", "-o", d / "c.png", "--csv", d / "c.png"], []),
        "check_capture_json_onto_image": (["check-capture", d, "--protocol", "transmission", "--json", photo],
                                          [photo]),
        "fit_sequence_json_onto_frame": (["fit-sequence", photo, "--envmap", env, "--disc", "12,12,8", "--workers",
                                          "0", "-o", d / "seq", "--json", photo, "--no-progress"], [photo, env]),
    }


@pytest.mark.parametrize("case", [
    "render_onto_envmap", "render_preview_onto_background", "render_json_onto_scene", "fit_prefix_onto_photo",
    "fit_json_onto_envmap", "calibrate_json_onto_photo", "calibrate_debug_onto_photo", "envmap_onto_probe_preview",
    "envmap_json_onto_probe", "chart_csv_is_output", "check_capture_json_onto_image", "fit_sequence_json_onto_frame",
    "chart_csv_onto_illuminant", "fit_json_onto_illuminant", "fit_json_onto_camera_response",
    "fit_sequence_json_onto_illuminant"])
def test_output_that_is_an_input_is_refused(case, files, tmp_path, capsys):
    argv, keep = _clashes(files, tmp_path)[case]
    before = _snapshot(*keep)
    rc, _, err = run_cli(capsys, argv)
    line = assert_one_line_error(rc, err)
    assert "refusing to write" in line, line
    assert _snapshot(*keep) == before
    assert_no_temp_files(tmp_path)
    if case == "chart_csv_is_output":
        assert not (tmp_path / "c.png").exists()


def test_render_on_a_full_disk_keeps_the_earlier_render(files, tmp_path, capsys):
    """The render succeeds, the disk is full: one line naming the reason; the earlier EXR and
    its preview are byte-identical (a 64 KiB tmpfs, mounted as root; skipped otherwise)."""
    import os
    import subprocess

    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    disk = tmp_path / "disk"
    disk.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(disk)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
    try:
        scene = write_scene(tmp_path, "scene.toml", scene_text(files["env"], width=64, height=64))
        out = disk / "out.exr"
        rc, _, err = run_cli(capsys, ["render", scene, "-o", out])
        assert rc == 0, err
        before = _snapshot(out, disk / "out.png")
        st = os.statvfs(disk)
        (disk / "filler").write_bytes(b"\0" * max(st.f_bavail * st.f_frsize - 512, 0))
        scene2 = write_scene(tmp_path, "scene2.toml", scene_text(files["env"], width=64, height=64).replace(
            "roughness = 0.05", "roughness = 0.2"))
        for argv in (["render", scene2, "-o", out], ["render", scene2, "-o", tmp_path / "x.exr", "--json",
                                                     disk / "r.json"]):
            rc, _, err = run_cli(capsys, argv)
            line = assert_one_line_error(rc, err)
            assert "no space left on device" in line, line
        assert _snapshot(out, disk / "out.png") == before
        assert not (disk / "r.json").exists()
        assert_no_temp_files(disk)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)


def test_json_to_dev_null_keeps_the_device(files, tmp_path, capsys):
    import os
    import stat

    before = os.stat("/dev/null")
    scene = write_scene(tmp_path, "scene.toml", scene_text(files["env"]))
    rc, _, err = run_cli(capsys, ["render", scene, "-o", tmp_path / "out.exr", "--json", "/dev/null"])
    assert rc == 0, err
    after = os.stat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_rdev == before.st_rdev


@pytest.mark.parametrize("state", ["missing", "unreadable"])
def test_fit_sequence_refuses_frames_without_run_json(state, files, tmp_path, capsys):
    """A folder with finished frames but no readable run.json: their settings are unknown,
    so they are not reused (nor run.json rewritten to claim them) without --force."""
    out = tmp_path / "seq"
    (out / "frames").mkdir(parents=True)
    frame = out / "frames" / "frame_000000.json"
    frame.write_text('{"version": 1, "frame": 0, "status": "ok"}\n')
    if state == "unreadable":
        (out / "run.json").write_text("{not json")
    before = _snapshot(*(p for p in out.rglob("*") if p.is_file()))
    rc, _, err = run_cli(capsys, ["fit-sequence", files["photo"], "--envmap", files["env"], "--disc", "12,12,8",
                                  "--workers", "0", "--no-progress", "-o", out])
    line = assert_one_line_error(rc, err)
    assert "run.json" in line and "--force" in line, line
    assert _snapshot(*(p for p in out.rglob("*") if p.is_file())) == before


def test_garbage_video_is_one_line_without_ffmpeg(files, tmp_path, capfd):
    """FFmpeg writes to the process's stderr itself: read it at the file-descriptor level."""
    video = tmp_path / "clip.mp4"
    video.write_bytes(np.random.default_rng(3).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    capfd.readouterr()
    try:
        rc = main(["fit-sequence", str(video), "--envmap", str(files["env"]), "--workers", "0", "-o",
                   str(tmp_path / "seq"), "--no-progress"])
    except SystemExit as exc:
        rc = exc.code
    _, err = capfd.readouterr()
    line = assert_one_line_error(rc, err)
    assert "video" in line, line


@pytest.mark.parametrize("disc", ["inf,1,2", "1,2,nan", "10,10,0"])
def test_disc_must_be_finite(disc, files, tmp_path, capsys):
    rc, _, err = run_cli(capsys, ["fit", files["photo"], "--envmap", files["env"], "--disc", disc])
    assert_one_line_error(rc, err)


def test_version(capsys):
    from bubblefit import __version__

    rc, out, _ = run_cli(capsys, ["--version"])
    assert rc == 0 and out.strip() == f"bubblefit {__version__}"


def test_parsers_import_nothing_heavy():
    """``--help`` and argument errors must not load JAX, OpenImageIO, colour-science, OpenCV,
    Dask, SciPy or Matplotlib (the start-up is timed in experiments/profile_startup.py)."""
    import subprocess
    import sys

    code = ("import sys\nfrom bubblefit.cli import build_parser\np = build_parser()\n"
            "for cmd in ['render', 'fit', 'fit-sequence', 'calibrate', 'envmap', 'chart', 'check-capture', 'demo']:\n"
            "    try:\n        p.parse_args([cmd, '--help'])\n    except SystemExit:\n        pass\n"
            "heavy = ('jax', 'OpenImageIO', 'colour', 'cv2', 'dask', 'distributed', 'scipy', 'matplotlib')\n"
            "print('HEAVY:' + ','.join(m for m in heavy if m in sys.modules))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                       cwd=Path(__file__).resolve().parent.parent)
    assert r.returncode == 0, r.stderr
    line = [ln for ln in r.stdout.splitlines() if ln.startswith("HEAVY:")][-1]
    assert line == "HEAVY:", f"heavy modules imported by the parsers: {line}"


# --------------------------------------------------------------------------------------
# one output contract by construction: declared file arguments, sets of outputs
# --------------------------------------------------------------------------------------
#: Words in an option's metavar or help that say it names a file or a folder.
_FILE_WORDS = ("file", "path", "folder", "csv", ".json", ".exr", ".png", ".toml", "image", "photo", "map",
               "prefix", "out_dir", "out", "frames", "spectrum", "probe", "before", "after", "dir", "reading")


def test_every_file_argument_is_declared_as_input_or_output():
    """Every argument of every command that names a file or folder is declared with a path
    type of cli/common.py, so that the same-file guard knows it without a hand-written
    list; arguments that take no file (numbers, choices, flags) are not."""
    import argparse

    from bubblefit.cli import build_parser
    from bubblefit.cli import common

    path_types = (common.input_file, common.output_file, common.output_folder, common.output_prefix)
    not_files = {"--thickness", "--model", "--hold", "--disc", "--circle", "--ball", "--thickness-range",
                 "--wavelength-range", "--protocol", "--n-film", "--cauchy", "--response", "--merge",
                 "--scheduler", "--times", "--preview-exposure", "--rotation-deg", "--reference-region", "--set"}
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    undeclared = []
    for name, p in sub.choices.items():
        for a in p._actions:
            if isinstance(a, (argparse._HelpAction, argparse._StoreTrueAction, argparse._StoreConstAction,
                              argparse.BooleanOptionalAction)) or \
                    a.type in (int, float) or a.choices:
                continue
            flag = a.option_strings[-1] if a.option_strings else a.dest
            words = f"{a.metavar or ''} {a.help or ''} {flag}".lower()
            names_a_file = any(w in words for w in _FILE_WORDS)
            if a.type in path_types:
                continue
            if names_a_file and flag not in not_files:
                undeclared.append(f"{name} {flag}")
    assert not undeclared, f"file arguments without a path type: {undeclared}"


def test_a_missing_output_folder_is_refused_before_the_fit(files, tmp_path, capsys):
    """An output in a folder that does not exist is one line and exit 2 before any work:
    the fit never starts (the photo is not even read)."""
    import time

    t0 = time.perf_counter()
    rc, _, err = run_cli(capsys, ["fit", files["photo"], "--envmap", files["env"], "--t", "0.96",
                                  "--json", tmp_path / "missing" / "out.json"])
    line = assert_one_line_error(rc, err)
    assert rc == 2 and "does not exist" in line and time.perf_counter() - t0 < 5
    rc, _, err = run_cli(capsys, ["fit", files["photo"], "--envmap", files["env"], "--t", "0.96",
                                  "-o", tmp_path / "missing" / "P"])
    assert "does not exist" in assert_one_line_error(rc, err)


def test_a_non_utf8_path_is_one_line(files, tmp_path, capsys):
    """A folder name that is not UTF-8 (kept by Python as surrogates) is refused by the
    argument parser in one line, as input and as output."""
    import os

    bad = os.fsdecode(os.fsencode(str(tmp_path)) + b"/caf\xe9")
    rc, _, err = run_cli(capsys, ["calibrate", bad + "/a.png", files["photo"]])
    assert rc == 2 and "not a UTF-8 path" in err and len(err.strip().splitlines()) == 1
    rc, _, err = run_cli(capsys, ["calibrate", files["photo"], files["photo"], "--debug-image", bad + "/d.png"])
    assert rc == 2 and "not a UTF-8 path" in err and len(err.strip().splitlines()) == 1


def test_outputs_land_as_a_set_and_an_interrupt_removes_them(tmp_path):
    """Inside an output set, completed files wait as temporaries: an interrupt while the
    last is written removes them all and leaves the earlier set byte-identical; a set
    that completes replaces every file."""
    from bubblefit.io.atomic import atomic_path, output_set, remove_temporaries, write_json, write_text

    a, b = tmp_path / "a.json", tmp_path / "b.txt"
    write_json(a, {"old": 1})
    write_text(b, "old")
    before = _snapshot(a, b)
    with pytest.raises(KeyboardInterrupt):
        with output_set():
            write_json(a, {"new": 2})
            with atomic_path(b) as tmp:
                Path(tmp).write_text("half")
                raise KeyboardInterrupt
    assert _snapshot(a, b) == before
    assert_no_temp_files(tmp_path)
    with pytest.raises(KeyboardInterrupt):  # interrupted between the open and the close of a writer
        with atomic_path(b) as tmp:
            Path(tmp).write_text("half")
            remove_temporaries()  # what the command line does on SIGINT
            raise KeyboardInterrupt
    assert_no_temp_files(tmp_path)
    with output_set():
        write_json(a, {"new": 2})
        write_text(b, "new")
        assert _snapshot(a, b) == before  # nothing renamed until the set is complete
    assert b.read_text() == "new" and '"new"' in a.read_text()


def test_a_short_write_never_replaces_a_file(tmp_path, monkeypatch):
    """A writer that reports success but leaves fewer bytes than given (a full disk seen by
    no error) is caught by the size check; an image that does not read back whole is
    caught by the re-read; the earlier file stays."""
    import builtins

    from bubblefit.errors import OutputError
    from bubblefit.io import atomic
    from bubblefit.io.images import read_image

    target = tmp_path / "out.json"
    target.write_text("earlier")
    real_open = builtins.open

    class Short:
        def __init__(self, fh):
            self.fh = fh

        def write(self, data):
            return self.fh.write(data[: len(data) // 2])

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    monkeypatch.setattr(builtins, "open", lambda f, mode="r", *a, **k: Short(real_open(f, mode, *a, **k))
                        if "w" in mode and ".out." in str(f) else real_open(f, mode, *a, **k))
    with pytest.raises(OutputError, match="bytes written"):
        atomic.write_text(target, '{"a": 1}')
    monkeypatch.undo()
    assert target.read_text() == "earlier"
    assert_no_temp_files(tmp_path)

    img = tmp_path / "img.png"
    write_image(img, np.full((8, 8, 3), 0.5))
    good = img.read_bytes()
    import bubblefit.io.images as images

    def short_png(tmp, shown, spec, data):
        Path(tmp).write_bytes(good[: len(good) // 2])

    monkeypatch.setattr(images, "_write_oiio", short_png)
    with pytest.raises(OutputError, match="read back"):
        write_image(img, np.full((8, 8, 3), 0.25))
    assert img.read_bytes() == good and read_image(img).pixels.shape == (8, 8, 3)
    assert_no_temp_files(tmp_path)


@pytest.mark.slow
def test_a_closed_pipe_ends_quietly(files, tmp_path):
    """``bubblefit chart ... | head -c1``: the reader goes away; no traceback, no internal error."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "bubblefit", "chart", "--thickness", "0:100:50", "-o",
                             str(tmp_path / "c.png")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # nobody reads
    err = proc.stderr.read().decode()
    proc.wait(timeout=120)
    assert err == "" and proc.returncode == 141, (proc.returncode, err)


# --------------------------------------------------------------------------------------
# bad input: one line, exit 2, inputs unchanged
# --------------------------------------------------------------------------------------
def _bad_inputs(files, d: Path) -> dict:
    """name -> (argv, the inputs that must stay byte-identical, a word the line must hold)."""
    long = d / "long.png"
    write_image(long, np.full((1, 100000, 3), 0.5))
    black = d / "black.png"
    write_image(black, np.zeros((48, 48, 3)))
    lit = d / "lit.png"
    write_image(lit, _disc_photo(48, 48))
    jpg = d / "photo.jpg"
    write_image(jpg, _disc_photo(64, 64))
    raw = jpg.read_bytes()
    cut = d / "cut.jpg"
    cut.write_bytes(raw[: int(0.96 * len(raw))])
    env = files["env"]
    return {
        "fit_long_png": (["fit", long, "--envmap", env, "--t", "0.96"], [long], "too small"),
        "fit_black_photo_with_background": (["fit", black, "--envmap", env, "--background", lit, "--t", "0.96"],
                                            [black, lit], "bubble"),
        "fit_calibration_dev_zero": (["fit", lit, "--envmap", env, "--calibration", "/dev/zero"], [lit], "larger"),
        "calibrate_truncated_jpeg": (["calibrate", jpg, cut, "-q"], [jpg, cut], "truncated"),
        "calibrate_circle_beyond_the_image": (["calibrate", files["photo"], files["photo"], "--circle", "12,12,400"],
                                              [files["photo"]], "beyond"),
    }


@pytest.mark.parametrize("case", ["fit_long_png", "fit_black_photo_with_background", "fit_calibration_dev_zero",
                                  "calibrate_truncated_jpeg", "calibrate_circle_beyond_the_image"])
def test_bad_input_is_one_line_and_exit_2(case, files, tmp_path, capsys):
    argv, keep, word = _bad_inputs(files, tmp_path)[case]
    before = _snapshot(*keep)
    rc, _, err = run_cli(capsys, argv)
    line = assert_one_line_error(rc, err)
    assert rc == 2 and word in line, line
    assert _snapshot(*keep) == before
    assert_no_temp_files(tmp_path)


@pytest.mark.parametrize("how", ["disc", "calibration"])
def test_a_disc_with_300_digits_is_one_short_line(how, files, tmp_path, capsys):
    import json

    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"t": 0.96, "bubble": {"cx": 1e300, "cy": 12.0, "r": 8.0}}))
    extra = ["--disc", "1e300,12,8", "--t", "0.96"] if how == "disc" else ["--calibration", cal]
    rc, _, err = run_cli(capsys, ["fit", files["photo"], "--envmap", files["env"], *extra])
    line = assert_one_line_error(rc, err)
    assert rc == 2 and len(line) < 300 and "000000000000" not in line, line


_END_SCRIPT = """
import atexit, sys, threading
from bubblefit import cli
atexit.register(lambda: print(" exit handler", flush=True))
print("buffered", end="")  # still in stdout's buffer when the process is ended
if sys.argv[1] == "thread":  # another thread at work: left to the interpreter's own exit
    done = threading.Event()
    worker = threading.Thread(target=done.wait)
    worker.start()
    cli._end_process(3)
    print(" returned", end="")
    done.set()
    sys.exit(4)
cli._end_process(3)
print(" after the end")
"""


@pytest.mark.parametrize("mode", ["alone", "thread"])
def test_a_process_ended_by_the_command_line_keeps_its_exit_status_output_and_handlers(mode):
    """:func:`bubblefit.cli._end_process` (``fit`` and ``render`` run as the process's entry):
    the status it is given, stdout flushed, the ``atexit`` handlers run, nothing after it;
    with another thread at work it returns and the interpreter ends as usual."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", _END_SCRIPT, mode], capture_output=True, text=True, timeout=120)
    assert r.stderr == ""
    if mode == "alone":
        assert (r.returncode, r.stdout) == (3, "buffered exit handler\n")
    else:
        assert (r.returncode, r.stdout) == (4, "buffered returned exit handler\n")
