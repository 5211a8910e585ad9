"""Sequence fitting (:mod:`bubblefit.inverse.sequence`): a draining film, frame by frame, on Dask.

A short synthetic drainage sequence: a constant film whose thickness falls as
``d(t) = d0 exp(-t / tau)``, rendered with the project's forward model, with shot and
read noise and 8-bit sRGB quantisation, written as PNG files; one file is corrupt. The
fitted thicknesses must give back ``d0`` and ``tau``; one and two Dask workers must give
identical numbers; an interrupted run must resume without refitting finished frames.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.io.images import srgb_decode, write_image

D0, TAU = 900.0, 30.0  # nm, s: d(t) = D0 exp(-t / TAU), ~25 nm per frame (a slow film)
FPS = 1.0
N_FRAMES = 7
CORRUPT = 3  # index of the unreadable frame
SIZE, DISC = 48, (24.0, 24.0, 20.0)
CHUNK = 4  # chunks [0..3] and [4..6]: two tasks, one per worker


def _options():
    from bubblefit.capture.view import ORTHOGRAPHIC
    from bubblefit.inverse.fit import FitOptions

    # the disc is known (a fixed camera); the thickness search covers the drainage's range
    return FitOptions(disc=DISC, thickness_range=(300.0, 1300.0), model="paper",
                      view=ORTHOGRAPHIC)


@pytest.fixture(scope="module")
def data(tmp_path_factory, small_courtyard):
    """Frames folder, environment map file and EnvMap of the synthetic sequence."""
    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.io.images import read_image
    from bubblefit.model.render import render
    from bubblefit.model.scene import Scene

    root = tmp_path_factory.mktemp("sequence")
    env_path = root / "env.exr"
    # exposed so that the background straight behind the bubble (-z) reads 0.5, not clipped
    view = EnvMap.from_array(small_courtyard).lookup(np.asarray([[0.0, 0.0, -1.0]], np.float32))
    write_image(env_path, small_courtyard * (0.5 / float(np.max(view))), bit_depth=32)
    env = EnvMap.from_array(read_image(env_path).pixels)
    frames = root / "frames"
    frames.mkdir()
    # the map is also the background seen through the bubble (what a fit without a
    # background photo assumes); the film tints it (as fits assume by default)
    base = {"camera": {"width": SIZE, "height": SIZE, "disc": list(DISC)}, "lighting": {"envmap": str(env_path)},
            "bubble": {"t": 0.972, "roughness": 0.015}, "effects": {"model": "paper", "transmission_tint": True}}
    cfg, _ = Scene.from_dict(dict(base, bubble=dict(base["bubble"], thickness_nm=D0))).config(env)
    rng = np.random.default_rng(7)
    truth = []
    for k in range(N_FRAMES):
        path = frames / f"frame_{k:03d}.png"
        if k == CORRUPT:
            path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)  # a truncated file
            truth.append(np.nan)
            continue
        d = D0 * np.exp(-(k / FPS) / TAU)
        truth.append(d)
        p = Scene.from_dict(dict(base, bubble=dict(base["bubble"], thickness_nm=float(d)))).params()
        img = np.asarray(render(p, cfg, env), np.float64)
        sigma = np.sqrt(0.01**2 * np.clip(img, 0, None) + 0.002**2)  # shot + read noise
        write_image(path, np.clip(img + rng.normal(size=img.shape) * sigma, 0, 1))  # 8-bit sRGB PNG
    return {"root": root, "frames": frames, "env_path": env_path, "env": env, "truth": np.asarray(truth)}


@pytest.fixture(scope="module")
def client():
    """A local Dask cluster of two single-threaded worker processes, for the whole module."""
    from distributed import Client, LocalCluster

    from bubblefit.inverse import local_env

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                           env=local_env(), silence_logs=40)
    c = Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def runs(data, client):
    """The sequence fitted on one worker, then on two (the second reads the first's compilation cache)."""
    from bubblefit.inverse.sequence import SequenceOptions, fit_sequence

    out = {}
    for n in (1, 2):
        seen = set()  # workers that fitted frames (a seam repair may later refit a chunk elsewhere)
        seq = SequenceOptions(scheduler=client, workers=n, chunk_size=CHUNK, fps=FPS, progress=False)
        out[n] = fit_sequence(data["frames"], data["env"], data["root"] / f"out{n}", _options(), seq,
                              on_record=lambda r: r["status"] == "ok" and seen.add(r["worker"]))
        out[n].extra["seen"] = seen
    return out


def _table(res):
    from bubblefit.inverse.sequence import read_table

    return read_table(res.table)


@pytest.mark.slow
def test_recovers_drainage_law(data, runs):
    res = runs[1]
    ok = [r for r in res.records if r["status"] == "ok"]
    assert len(ok) == N_FRAMES - 1
    assert all(r["converged"] for r in ok)
    t = res.column("time_s")
    d = res.column("thickness_nm")
    err = res.column("thickness_nm_stderr")
    good = np.isfinite(d)
    assert good.sum() == N_FRAMES - 1
    # each frame's thickness inside 4 of its own error bars or within 5 nm of the truth (the
    # 8-bit steps of a 48 px photo bias a film by a few nm, more than its noise-based error bar)
    assert np.all(np.isfinite(err[good])) and np.all(err[good] > 0)
    miss = np.abs(d[good] - data["truth"][good])
    assert np.all(miss <= np.maximum(4.0 * err[good], 5.0)), (miss, err[good])
    # the law: log d = log d0 - t / tau, weighted least squares
    w = (d[good] / err[good]) ** 2
    slope, intercept = np.polyfit(t[good], np.log(d[good]), 1, w=np.sqrt(w))
    tau, d0 = -1.0 / slope, np.exp(intercept)
    assert abs(tau - TAU) < 0.05 * TAU, tau
    assert abs(d0 - D0) < 0.02 * D0, d0
    # warm starts: every frame but the first started from its neighbour; the second chunk's
    # global search was joined to the first chunk's chain (a seam repair) or agreed with it
    warm = {r["frame"]: r["warm_start"] for r in ok}
    assert warm[0] is False and all(warm[k] for k in (1, 2, 5, 6))
    assert warm[4] or res.records[4].get("seam_checked")


def test_warm_starts_carry_the_thickness_on():
    """A frame starts from the last frame's values with its thicknesses carried on linearly
    from the two last (a smooth drainage starts within a fraction of a nanometre); the
    other values stay, a film never starts below 1 nm, and without a frame before there
    is nothing to carry on. The batched solve's starts are the same rule k frames ahead."""
    from bubblefit.inverse import extrapolated

    last = {"thickness_nm": 780.0, "top_nm": 300.0, "t": 0.97, "exposure": 1.1}
    before = {"thickness_nm": 800.0, "top_nm": 290.0, "t": 0.96, "exposure": 1.3}
    start = extrapolated(last, before)
    assert start == {"thickness_nm": 760.0, "top_nm": 310.0, "t": 0.97, "exposure": 1.1}
    assert extrapolated(last, before, 3)["thickness_nm"] == pytest.approx(720.0)
    assert extrapolated(last, {"thickness_nm": 1600.0})["thickness_nm"] == 1.0
    assert extrapolated(last, None) == last and extrapolated(last, None) is not last
    d = 900.0 * np.exp(-np.arange(4) / 40.0)  # the draining film of experiments/bench_sequence.py
    guess = extrapolated({"thickness_nm": d[2]}, {"thickness_nm": d[1]})["thickness_nm"]
    assert abs(guess - d[3]) < 0.03 * abs(d[2] - d[3])


def test_warm_starts_carry_the_refined_disc_on():
    """A frame whose fit refined its disc hands the refined disc (pixels) on in its warm
    start, and the next frame's refinement starts there: :func:`disc_start` inverts
    :func:`refined_disc` to the rounding of its pixels (0.0005 px over a 38 px radius); a
    move beyond the refinement's range, or no disc, starts nothing. A disc that was not
    refined is not handed on."""
    from bubblefit.inverse import base_record, disc_start, refined_disc, result_record
    from bubblefit.inverse._parameters import DISC_LIMIT, DISC_PARAMETERS
    from bubblefit.inverse.sequence import FrameRef

    found = (49.64, 48.01, 38.03)
    moves = {"disc_x": 0.0074, "disc_y": -0.0021, "disc_r": 0.0097}
    refined, _ = refined_disc(found, dict(moves), {})
    start = disc_start(found, refined)
    assert set(start) == set(DISC_PARAMETERS)
    for name in DISC_PARAMETERS:
        assert abs(start[name] - moves[name]) <= 0.0005 / found[2] * (1 + 1e-9)
    assert disc_start(found, (found[0] + 1.01 * DISC_LIMIT * found[2], found[1], found[2])) == {}
    assert disc_start(found, None) == {} and disc_start(found, (1.0, 2.0)) == {}

    class Result:
        params = {"top_nm": 240.0}
        stderr = {"top_nm": 0.7}
        converged = True
        disc = refined
        disc_stderr = {"cx": 0.01, "cy": 0.01, "r": 0.01}

    class Given(Result):
        disc_stderr = None

    base = base_record(FrameRef(0, "a.png", 0.0), None)
    rec = result_record(base, Result(), 1.0)
    assert rec["init"] == {"top_nm": 240.0, "disc": list(refined)} and "disc" not in rec["params"]
    assert "disc" not in result_record(base, Given(), 1.0)["init"]


@pytest.mark.slow
def test_failed_frame_recorded(runs):
    res = runs[1]
    bad = res.records[CORRUPT]
    assert bad["status"] == "failed" and not bad["converged"]
    assert "cannot read frame" in bad["message"]
    rows = _table(res)
    assert rows[CORRUPT]["status"] == "failed" and rows[CORRUPT]["thickness_nm"] is None
    assert res.failed == 1
    # the JSON lines hold the same rows, with null for the missing values
    lines = [json.loads(x) for x in res.jsonl.read_text().splitlines()]
    assert [x["frame"] for x in lines] == list(range(N_FRAMES))
    assert lines[CORRUPT]["thickness_nm"] is None and lines[0]["thickness_nm"] == rows[0]["thickness_nm"]


@pytest.mark.slow
def test_one_and_two_workers_agree(runs):
    one, two = _table(runs[1]), _table(runs[2])
    assert len(runs[2].extra["seen"]) == 2 and len(runs[1].extra["seen"]) == 1  # both workers took part
    assert runs[1].workers == 1 and runs[2].workers == 2
    skip = {"worker", "fit_time_s"}
    for a, b in zip(one, two):
        for k in a:
            if k not in skip:
                assert a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]), (k, a[k], b[k])


@pytest.mark.slow
def test_vectorised_batches_agree(data, runs):
    """Frames fitted together (one vmapped solve, fit.fit_batch) give the per-frame fits'
    thicknesses within their error bars; an unreadable frame in a batch is recorded and
    the batch goes on. In this process, without Dask, one chunk of all frames."""
    from bubblefit.inverse.sequence import SequenceOptions, fit_sequence

    seq = SequenceOptions(workers=0, chunk_size=N_FRAMES, fps=FPS, progress=False, batch=4)
    res = fit_sequence(data["frames"], data["env"], data["root"] / "batched", _options(), seq)
    by_frame = {r["frame"]: r for r in res.records}
    assert by_frame[CORRUPT]["status"] == "failed" and "cannot read" in by_frame[CORRUPT]["message"]
    batched = [r for r in res.records if r.get("batch")]
    assert len(batched) >= 3 and all("batched warm start" in r["message"] for r in batched)
    one = runs[1].column("thickness_nm")
    d, err = res.column("thickness_nm"), res.column("thickness_nm_stderr")
    good = np.isfinite(d)
    assert good.sum() == N_FRAMES - 1
    assert np.all(np.abs(d[good] - one[good]) < np.maximum(3 * err[good], 0.5)), (d, one)
    assert np.all(np.abs(d[good] - data["truth"][good]) < 0.02 * data["truth"][good])


@pytest.mark.slow
def test_tables_and_plot(runs):
    res = runs[2]
    header = res.table.read_text().splitlines()[0].split(",")
    assert header[:8] == ["frame", "file", "converged", "thickness_nm", "thickness_nm_stderr", "t", "roughness",
                          "exposure"]
    assert "roughness_stderr" in header and "time_s" in header
    assert res.plot is not None and res.plot.stat().st_size > 1000
    assert not [p for p in res.out_dir.rglob(".*") if p.is_file()]  # no temporary files left


@pytest.mark.slow
def test_resume_after_interrupt(data, runs, client):
    """Finished frames are never refitted; the resumed run gives the same numbers."""
    from bubblefit.inverse.sequence import SequenceOptions, fit_sequence

    src = runs[1].out_dir
    out = data["root"] / "resume"
    shutil.copytree(src, out)
    for k in (5, 6):  # an interrupted run: these frames never finished
        os.remove(out / "frames" / f"frame_{k:06d}.json")
    os.remove(out / "params.csv")
    kept = {p.name: (p.stat().st_mtime_ns, p.read_bytes()) for p in (out / "frames").iterdir()}

    class Stop(Exception):
        pass

    def stop_after_first(rec):
        raise Stop  # the user presses Ctrl-C once frame 5 is saved

    seq = SequenceOptions(scheduler=client, workers=1, chunk_size=CHUNK, fps=FPS, progress=False)
    with pytest.raises(Stop):
        fit_sequence(data["frames"], data["env"], out, _options(), seq, on_record=stop_after_first)
    assert (out / "frames" / "frame_000005.json").exists()
    res = fit_sequence(data["frames"], data["env"], out, _options(), seq)
    assert res.fitted == 1  # frame 6 only: frame 5 was saved before the stop
    assert res.skipped == N_FRAMES - res.fitted
    for name, (mtime, body) in kept.items():
        p = out / "frames" / name
        assert p.stat().st_mtime_ns == mtime and p.read_bytes() == body
    assert np.array_equal(res.column("thickness_nm"), runs[1].column("thickness_nm"), equal_nan=True)
    assert np.array_equal(res.column("exposure_stderr"), runs[1].column("exposure_stderr"), equal_nan=True)


@pytest.mark.slow
def test_cli_resumes_finished_run(data, runs, capsys):
    """``bubblefit fit-sequence`` on a finished folder refits nothing and rebuilds the tables."""
    from bubblefit.cli import main

    out = data["root"] / "cli"
    shutil.copytree(runs[1].out_dir, out)
    os.remove(out / "params.csv")
    argv = ["fit-sequence", str(data["frames"]), "--envmap", str(data["env_path"]), "--disc", "24,24,20",
            "--model", "paper", "--fov", "0", "--thickness-range", "300,1300", "--chunk-size", str(CHUNK),
            "--workers", "0", "-o", str(out), "--json", str(out / "summary.json"), "--no-progress"]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fitted"] == 0 and summary["skipped"] == N_FRAMES and summary["failed"] == 1
    assert summary["failures"][0]["frame"] == CORRUPT
    assert (out / "params.csv").read_text() == runs[1].table.read_text()
    # other settings into the same folder: refused, not mixed
    assert main(argv[:-1] + ["--thickness-range", "200,1300"]) == 2
    assert "other settings" in capsys.readouterr().err
    assert main(["fit-sequence", str(data["frames"]), "--envmap", str(data["env_path"]), "-o", str(out),
                 "--chunk-size", "0"]) == 2


def test_discover_frames(tmp_path):
    """Folders sort naturally; a video's frames decode from 8-bit sRGB BGR to linear RGB."""
    import cv2

    from bubblefit.inverse.sequence import discover_frames, load_frame

    for name in ("f10.png", "f2.png", "f1.png", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    refs = discover_frames(tmp_path, fps=25)
    assert [os.path.basename(r.source) for r in refs] == ["f1.png", "f2.png", "f10.png"]
    assert refs[2].time_s == pytest.approx(2 / 25)
    with pytest.raises(InputError):
        discover_frames(tmp_path / "missing.png")
    with pytest.raises(InputError):
        discover_frames(tmp_path / "*.jpg")

    video = tmp_path / "clip.avi"
    codes = [(40, 120, 200), (200, 60, 10), (90, 90, 90)]  # RGB codes of three flat frames
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (32, 24))
    for rgb in codes:
        w.write(np.full((24, 32, 3), rgb[::-1], np.uint8))  # OpenCV writes BGR
    w.release()
    refs = discover_frames(video)
    assert len(refs) == 3 and refs[1].time_s == pytest.approx(1 / 30) and refs[2].label.endswith("#2")
    for ref, rgb in zip(reversed(refs), reversed(codes)):  # out of order: the reader seeks
        px = load_frame(ref)
        assert px.shape == (24, 32, 3)
        np.testing.assert_allclose(px.mean(axis=(0, 1)), srgb_decode(np.asarray(rgb) / 255.0), rtol=0.08, atol=0.004)


@pytest.mark.slow
def test_rows_say_ok(runs):
    """The unreadable frame is not ``ok``; a fitted frame's row is ``ok`` exactly when its fit
    is (and then carries no warning), and a row that is not says why; no frame of this real
    sequence is flagged as a jump (the flags do not fire on noise). The photos were rendered
    with a mirror lookup (``auto`` found the film's roughness, 0.015, below what it needs to
    filter), so the fits drift towards a mirror: an upper limit on the roughness, not a fit
    at a bound."""
    rows = _table(runs[1])
    recs = {r["frame"]: r for r in runs[1].records}
    assert not rows[CORRUPT]["ok"]
    for k, r in enumerate(rows):
        if k == CORRUPT:
            continue
        assert r["ok"] == (recs[k].get("fit_ok", True) is not False and bool(recs[k].get("converged"))), k
        assert r["ok"] or r["warnings"], k
    assert sum(r["ok"] for r in rows) >= N_FRAMES - 2
    smooth = [k for k in recs if k != CORRUPT and recs[k]["params"]["roughness"] < 3 * recs[k]["stderr"]["roughness"]]
    assert smooth and all("upper limit" in recs[k]["message"] for k in smooth)
    assert not any(r.get("jumps") for r in runs[1].records)


def _stub_record(k: int, roughness: float, exposure: float, *, stderr: float = 1e-4) -> dict:
    return {"frame": k, "file": f"f{k}.png", "time_s": float(k), "status": "ok", "converged": True,
            "params": {"thickness_nm": 900.0 - 5 * k, "t": 0.97, "roughness": roughness, "exposure": exposure},
            "stderr": {"thickness_nm": 1.0, "roughness": stderr * roughness, "exposure": stderr * exposure}}


def test_jumping_roughness_or_gain_is_flagged(tmp_path):
    """A frame whose roughness (or gain) leaves its neighbours' is flagged, in its record and
    in its row (``ok`` false, a warning in words); a slow drift and noise are not."""
    from bubblefit.inverse import flag_jumps, write_tables

    rng = np.random.default_rng(5)
    n = 12
    rough = 0.015 * (1 + 0.004 * np.arange(n)) * (1 + 0.01 * rng.normal(size=n))  # drift + 1 % noise
    gain = np.full(n, 1.2) * (1 + 0.01 * rng.normal(size=n))
    rough[4] *= 3.0  # a reflection fitted as a rough film
    gain[9] *= 0.5  # a frame of another exposure
    records = [_stub_record(k, float(rough[k]), float(gain[k])) for k in range(n)]
    records.append({"frame": n, "file": "bad.png", "time_s": float(n), "status": "failed", "converged": False})
    flagged = flag_jumps(records)
    assert [r["frame"] for r in flagged if r.get("jumps")] == [4, 9]
    assert flagged[4]["jumps"] == ["roughness"] and flagged[9]["jumps"] == ["exposure"]
    assert not records[4].get("jumps")  # the input records are left as they were
    csv_path, jsonl_path = write_tables(tmp_path, flagged)
    from bubblefit.inverse.sequence import read_table

    rows = read_table(csv_path)
    assert [r["ok"] for r in rows] == [k not in (4, 9) for k in range(n)] + [False]
    assert "roughness jumps" in rows[4]["warnings"] and "exposure jumps" in rows[9]["warnings"]
    lines = [json.loads(x) for x in jsonl_path.read_text().splitlines()]
    assert lines[4]["ok"] is False and lines[5]["ok"] is True


def test_fit_reported_not_ok_is_not_ok(tmp_path):
    """A fit that says ``ok = False`` itself (read with defaults, for results with and without
    the field) makes its row not ok, and its warnings reach the table."""
    from bubblefit.inverse import base_record, result_record
    from bubblefit.inverse import row_ok
    from bubblefit.inverse.sequence import FrameRef

    class Result:
        params = {"thickness_nm": 500.0}
        stderr = {"thickness_nm": 2.0}
        converged = True
        message = ""
        iterations = 9
        residual_rms = 0.01

    class Flagged(Result):
        ok = False
        reduced_chi2 = 7.5
        warnings = ["roughness at its bound"]

    base = base_record(FrameRef(0, "a.png", 0.0), None)
    assert row_ok(result_record(base, Result(), 1.0))
    rec = result_record(base, Flagged(), 1.0)
    assert not row_ok(rec) and rec["warnings"] == ["roughness at its bound"] and rec["reduced_chi2"] == 7.5


@pytest.mark.slow
def test_resume_refused_without_run_json(data, runs):
    """Finished frames whose run.json is gone or damaged are not reused: refused, untouched."""
    from bubblefit.inverse.sequence import SequenceOptions, fit_sequence

    for damage in ("delete", "garble"):
        out = data["root"] / f"no_run_{damage}"
        shutil.copytree(runs[1].out_dir, out)
        if damage == "delete":
            os.remove(out / "run.json")
        else:
            (out / "run.json").write_bytes(b"\x00garbage")
        before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
        with pytest.raises(InputError, match="run.json"):
            fit_sequence(data["frames"], data["env"], out, _options(),
                         SequenceOptions(workers=0, chunk_size=CHUNK, fps=FPS, progress=False))
        assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


#: What :func:`_scripted_fit` was asked, one (frame, model, warm-started) per call.
SCRIPTED_CALLS: list = []


def _scripted_fit(photo, env, *, options, background=None, init=None, scene=None):
    """A stand-in for ``fit_photo`` (``fit_function="test_sequence:_scripted_fit"``): the frame's
    number is its pixels' value; ``auto`` keeps the physical model, which explains every frame
    but frame 2 when asked for by name (the kept model's fit that must fall back)."""
    from types import SimpleNamespace

    k = int(round(float(np.mean(photo)) * 10))
    SCRIPTED_CALLS.append((k, options.model, init is not None))
    floor = 5.0 if (k == 2 and options.model != "auto") else 0.9
    return SimpleNamespace(params={"top_nm": 200.0 - k, "bottom_nm": 900.0, "exponent": 1.0, "t": 0.97},
                           stderr={}, converged=True, message="", iterations=3, residual_rms=0.01,
                           ok=floor <= options.judge.ok_chi2, chi2_floor=floor, reduced_chi2=floor,
                           model="physical")


def test_warm_started_frame_keeps_the_previous_model(tmp_path):
    """Under ``auto`` the first frame compares the models; a warm-started frame fits the model
    its predecessor kept (it explained that frame), alone; a frame that model does not
    explain falls back to the full ``auto`` fit, and its record says so. ``model_kept``
    marks the frames that kept it."""
    import sys

    from bubblefit.inverse.fit import FitOptions
    from bubblefit.inverse._executors import fit_chunk
    from bubblefit.inverse.sequence import FrameRef

    sys.modules.setdefault("test_sequence", sys.modules[__name__])
    refs = []
    for k in range(4):
        path = tmp_path / f"f{k}.exr"
        write_image(path, np.full((4, 4, 3), k / 10.0, np.float32), bit_depth=32)
        refs.append(FrameRef(k, str(path), float(k)))
    SCRIPTED_CALLS.clear()
    recs = fit_chunk([(r, None) for r in refs], None, FitOptions(model="auto"), None, None, {}, False,
                     "test_sequence:_scripted_fit")
    assert SCRIPTED_CALLS == [(0, "auto", False), (1, "physical", True), (2, "physical", True), (2, "auto", True),
                              (3, "physical", True)]
    assert [r.get("model_kept") for r in recs] == [None, "physical", None, "physical"]
    assert "fallback" in recs[2] and "physical model kept" in recs[2]["fallback"]
    assert all(r["model"] == "physical" and r["chi2_floor"] == 0.9 for r in recs)
    SCRIPTED_CALLS.clear()  # a model named by the user is never replaced
    fit_chunk([(r, None) for r in refs[:2]], None, FitOptions(model="paper"), None, None, {}, False,
              "test_sequence:_scripted_fit")
    assert [m for _, m, _ in SCRIPTED_CALLS] == ["paper", "paper"]


def test_warm_map_follows_the_profile():
    """The next frame's map starts from the previous frame's map moved by the change of the
    fitted drainage profile (the map's own features carried, the profile's drainage
    applied); pixels the previous map lacks take the profile; a map covering under
    ``WARM_COVER`` of the film starts nothing. A start that holds a map and its profile
    starts the map of a frame of the same size."""
    from types import SimpleNamespace

    from bubblefit.inverse._maps import WARM_COVER, profile_map, warm_centre
    from bubblefit.inverse._setup import map_start

    h = np.linspace(-1.0, 1.0, 20)[:, None] * np.ones((1, 20))
    lev = SimpleNamespace(height=h, mask=np.ones((20, 20), bool))
    p0, p1 = (250.0, 1000.0, 1.2), (240.0, 980.0, 1.2)
    bump = 30.0 * np.exp(-((np.arange(20) - 10.0) ** 2) / 8.0)[None, :] * np.ones((20, 1))
    prev = profile_map(lev, p0) + bump
    prev[0, :3] = np.nan
    got = warm_centre(lev, p1, (prev, p0))
    want = profile_map(lev, p1) + bump
    want[0, :3] = profile_map(lev, p1)[0, :3]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-9)
    sparse = prev.copy()
    sparse[: int(np.ceil(20 * (1 - WARM_COVER))) + 1] = np.nan  # one row more than the least cover allows
    assert warm_centre(lev, p1, (sparse, p0)) is None
    nxt = {"top_nm": 250.0, "map": prev, "map_profile": p0}
    assert map_start(nxt, (20, 20))[1] == p0 and map_start(nxt, (10, 10)) is None


@pytest.mark.slow
def test_warm_started_maps_stay_within_the_targets(tmp_path):
    """A short draining film from the independent reference renderer (the first three 96 px
    frames of ``experiments/bench_sequence_maps.py``, 2x2 rays a pixel, which thin by 10-20
    nm a frame; at 1 ray a pixel its glints leave the photo unexplained), fitted as
    ``fit-sequence --thickness map --maps`` does: the frames after the first keep the model
    the first one chose (or fall back to the full fit, recorded), and every map meets the
    validation targets (``validate.py``: median error within 15 nm, 90 % of the inner disc
    within 15 nm, no order hops)."""
    import sys
    from pathlib import Path

    here = Path(__file__).resolve().parent.parent / "experiments"
    for p in (here, here / "validation"):
        if str(p) not in sys.path:
            sys.path.insert(0, str(p))
    import bench_sequence_maps as bench
    import validate

    frames = tmp_path / "frames"
    meta = bench.render_frames(frames, 3, 96, 2)
    argv = [*sorted(str(p) for p in frames.glob("frame_*.png")), "--envmap",
            str(Path(validate.DATA) / "envmaps" / "sunset.exr"), "--background", str(frames / "background.png"),
            "--thickness", "map", "--maps", "--fov", "0", "--illuminant", "D65", "--workers", "0"]
    bench.run_pass(argv, tmp_path / "run")
    recs = [json.loads((tmp_path / "run" / "frames" / f"frame_{k:06d}.json").read_text()) for k in range(3)]
    from bubblefit.inverse.fit import FitOptions

    ok_chi2 = FitOptions().judge.ok_chi2
    assert recs[0]["converged"] and recs[0]["chi2_floor"] <= ok_chi2  # the premise: the film is explained
    for before, rec in zip(recs, recs[1:]):
        explained = before["converged"] and before["chi2_floor"] <= ok_chi2
        assert rec.get("model_kept") == before["model"] or "fallback" in rec or not explained
    scores = bench.score(tmp_path / "run", frames, meta)
    assert all(s["meets"] for s in scores), scores


def test_profile_from_a_map_and_its_standard_errors():
    """The drainage profile fitted to a map by variable projection comes back from a map
    that is the profile plus independent Gaussian noise of the map's stated standard
    errors, and its standard errors are honest: over independent noise draws the errors'
    z-scores have unit spread (the spread of a sample standard deviation of n draws is
    about 1 / sqrt(2 n): the bounds are 4 of those; the larger of two estimates of each
    variance widens them a little)."""
    from types import SimpleNamespace

    from bubblefit.inverse._maps import profile_from_map, profile_map

    n = 40
    h = np.linspace(-1.0, 1.0, n)[:, None] * np.ones((1, n))
    lev = SimpleNamespace(height=h, mask=np.ones((n, n), bool), cfg=SimpleNamespace(camera=None))
    truth = (230.0, 960.0, 1.2)
    clean = profile_map(lev, truth)
    sigma = np.full((n, n), 4.0)
    rng = np.random.default_rng(5)
    draws = 100
    z = []
    for _ in range(draws):
        got, err = profile_from_map(lev, clean + sigma * rng.standard_normal((n, n)), sigma, (240.0, 980.0, 1.0))
        z.append([(g - t) / err[name] for g, t, name in zip(got, truth, ("top_nm", "bottom_nm", "exponent"))])
    z = np.asarray(z)
    spread = z.std(axis=0)
    bound = 4.0 / np.sqrt(2 * draws)
    assert np.all(np.abs(spread - 1.0) < bound), spread
    assert np.all(np.abs(z.mean(axis=0)) < 4.0 / np.sqrt(draws)), z.mean(axis=0)
    held, err = profile_from_map(lev, clean, sigma, truth, free=("top_nm", "bottom_nm"))
    assert held[2] == truth[2] and "exponent" not in err
    np.testing.assert_allclose(held[:2], truth[:2], atol=1e-6)


def test_exposure_score_test_and_step():
    """With the map held, the exposure's closed-form step on a render affine in the exposure
    (``B + E A``) recovers a moved exposure to within its stated standard error's 4, and
    a frame whose exposure did not move takes the step (score statistic over the chi^2
    quantile of 1 degree of freedom) in ``EXPOSURE_TEST_ALPHA`` of noise draws, within 4
    binomial standard errors."""
    from types import SimpleNamespace

    from scipy.stats import chi2

    from bubblefit.inverse._uncertainty import Misfit
    from bubblefit.inverse import FitOptions
    from bubblefit.inverse._carried import EXPOSURE_TEST_ALPHA, exposure_step

    rng = np.random.default_rng(7)
    shape = (30, 30, 3)
    a_true, b = rng.uniform(0.2, 0.8, shape), rng.uniform(0.0, 0.2, shape)
    sigma = 0.01
    opts = FitOptions()
    e0 = 0.6
    lev = SimpleNamespace(w=np.full(shape, 1.0 / sigma), y=b + e0 * a_true)
    floor = np.sqrt(sigma**2 + (float(opts.judge.model_error) * lev.y) ** 2)
    one = Misfit(1.0, 1.0, 1.0, 0.0, 1.0)
    img = b + e0 * a_true  # its column, the derivative in the exposure, is a_true
    draws, hits = 1000, 0
    for _ in range(draws):
        photo = img + floor * rng.standard_normal(shape)
        hits += exposure_step(lev, photo, img, a_true, opts, one)[1] > chi2.ppf(1 - EXPOSURE_TEST_ALPHA, 1)
    rate = hits / draws
    assert abs(rate - EXPOSURE_TEST_ALPHA) < 4 * np.sqrt(EXPOSURE_TEST_ALPHA * (1 - EXPOSURE_TEST_ALPHA) / draws)
    photo = b + 0.62 * a_true + floor * rng.standard_normal(shape)
    step, z2, err = exposure_step(lev, photo, img, a_true, opts, one)
    assert abs(e0 + step - 0.62) < 4 * err and z2 > chi2.ppf(1 - EXPOSURE_TEST_ALPHA, 1)


def test_held_frames_take_the_effects_decided_for_the_same_values(monkeypatch):
    """A sequence's frames that start from the same values over the same map take the
    effects their first frame decided (the films are not bounded again); another starting
    value or another map is decided anew."""
    import bubblefit.inverse._setup as S
    from bubblefit.inverse.fit import FitOptions
    from bubblefit.lighting.envmap import EnvMap

    calls = []

    def counted(summary, settings, *, thickness_kind, tolerance):
        calls.append(summary.t)
        return ("effects", [f"decision {len(calls)}"])

    monkeypatch.setattr(S, "resolve", counted)
    monkeypatch.setattr(S, "_DECIDED", {})
    opts = FitOptions()
    vals, _ = S.defaults(None, None, opts)
    env = EnvMap.from_array(np.full((8, 16, 3), 0.25))
    first = S._decide(opts, vals, env, None, {}, None, ())
    again = S._decide(opts, dict(vals), env, None, {}, None, ())
    assert again == first and len(calls) == 1
    S._decide(opts, dict(vals, t=vals["t"] * 0.5), env, None, {}, None, ())
    S._decide(opts, vals, EnvMap.from_array(np.full((8, 16, 3), 0.25)), None, {}, None, ())
    assert len(calls) == 3
