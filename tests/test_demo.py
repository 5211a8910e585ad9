"""The demo's pipeline end to end at a small size: synthesise (noise, 8-bit files),
calibrate, fit, and compare every recovered value with the truth within the tolerances
the demo states (:data:`bubblefit.demo.TOLERANCES`)."""

from __future__ import annotations

import json

import numpy as np
import pytest

# the whole demo (synthesise, calibrate, fit) runs once for this module
pytestmark = pytest.mark.slow

SIZE = 64


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from bubblefit.demo import run_demo

    out = tmp_path_factory.mktemp("demo")
    return out, run_demo(out, size=SIZE, seed=3, progress=False)


def test_recovered_values_within_stated_tolerances(demo):
    from bubblefit.demo import TOLERANCES, format_table

    _, result = demo
    table = format_table(result["rows"])
    names = {r["name"] for r in result["rows"]}
    assert names == set(TOLERANCES), table
    for r in result["rows"]:
        kind, tol = TOLERANCES[r["name"]]
        got, true = r["recovered"], r["true"]
        assert got is not None and np.isfinite(got), table
        err = abs(got - true) if kind == "abs" else abs(got - true) / abs(true)
        assert err <= tol, f"{r['name']}: true {true}, recovered {got}, tolerance {tol} ({kind})\n{table}"
    assert result["all_ok"]


def test_exposure_is_unbiased(demo):
    """The exposure (the gain of the photo) within 3 of its stated standard errors, or 2 %,
    of the truth: what an unbiased fit gives. It came out about 5 % low while the fit took
    the noisy background photo for the true light behind the film; with the background's
    noise in each pixel's weight it is unbiased."""
    _, result = demo
    r = {r["name"]: r for r in result["rows"]}["exposure"]
    miss = abs(r["recovered"] - r["true"])
    assert miss <= max(3 * r["stderr"], 0.02 * abs(r["true"])), (r["recovered"], r["true"], r["stderr"])


def test_demo_fit_converges_and_says_so(demo):
    """The demo's own fit converges (not stopped at its step limit) and is ok, and its
    report states that as it is."""
    out, result = demo
    fit = result["fit"]
    assert fit["converged"] is True and fit["status"] == "converged", result["status"]
    assert fit["ok"] is True, result["status"]
    assert result["status"].startswith("fit ok: yes; converged")
    assert result["status"].split("\n")[0] in (out / "index.html").read_text()


def test_standard_errors_are_given_and_plausible(demo):
    _, result = demo
    rows = {r["name"]: r for r in result["rows"]}
    for name in ("t (calibrate)", "t (fit)", "roughness", "top_nm", "bottom_nm", "exposure"):
        s = rows[name]["stderr"]
        assert s is not None and s > 0, name
    # the calibrated t agrees with the truth within a few standard errors (or 0.002, for bias of 8-bit steps)
    r = rows["t (calibrate)"]
    assert abs(r["recovered"] - r["true"]) <= max(5 * r["stderr"], 0.002)


def test_report_files_written(demo):
    out, result = demo
    for key in ("report", "html", "results", "photo", "before", "after", "render", "thickness"):
        assert (out / result["paths"][key].split("/")[-1]).exists(), key
    saved = json.loads((out / "results.json").read_text())
    assert saved["fit"]["params"]["top_nm"] == pytest.approx(result["fit"]["params"]["top_nm"])
    html = (out / "index.html").read_text()
    assert "photo_render.png" in html and "top_nm" in html
