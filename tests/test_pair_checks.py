"""A photo and its background photo are checked before a fit: swapped files and a background
of another scene are refused in one line; an exposure a film cannot give is not ok.

The pairs are rendered here (bubblefit's renderer, the paper model over a background
photo), with read and shot noise and 8-bit sRGB quantisation; the references for the
physical floors (Fresnel, Airy, the CIE observer) are written independently of the package
(``tests/helpers.py``, colour-science).
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from helpers import airy_reflectance, fresnel_rs_rp, quantise_8bit, smooth_backdrop

SIZE = 48
DISC = (24.3, 23.6, 17.0)


def _sigma(img):
    from bubblefit.inverse import noise_sigma

    return noise_sigma(img, 2e-3, 2e-4, 8)


@pytest.fixture(scope="module")
def pair():
    """``(photo, background, other)``: a bubble (paper model, t 0.97, 420 nm) reflecting the
    shipped courtyard over a dim textured backdrop, the backdrop alone, and the view of
    another scene (a ramp from dark to bright across the frame, the brightness range of the
    backdrop and more), each noisy and 8-bit."""
    from bubblefit.model.scene import Scene, render_scene, shipped_envmap

    rng = np.random.default_rng(7)
    back = smooth_backdrop(rng, SIZE, lo=0.03, hi=0.25)
    other = np.broadcast_to(np.linspace(0.01, 0.5, SIZE)[None, :, None], (SIZE, SIZE, 3)) * back[::-1] / back.mean()
    scene = Scene.from_dict({"camera": {"width": SIZE, "height": SIZE, "disc": list(DISC)},
                             "bubble": {"t": 0.97, "f": 0.3, "roughness": 0.0, "thickness_nm": 420.0},
                             "lighting": {"envmap": str(shipped_envmap("courtyard"))},
                             "effects": {"model": "paper"}})
    clean = np.asarray(render_scene(scene, background=back), np.float64)
    return quantise_8bit(clean, rng), quantise_8bit(back, rng), quantise_8bit(other, rng)


def _geometry():
    y, x = np.mgrid[0:SIZE, 0:SIZE] + 0.5
    rho = np.hypot(x - DISC[0], y - DISC[1]) / DISC[2]
    inside = rho < 1.0
    return inside, np.sqrt(np.clip(1.0 - rho**2, 0.0, 1.0))


def _judge(photo, background):
    from bubblefit.inverse import judge_pair

    inside, cos = _geometry()
    usable = np.ones(inside.shape, bool)
    return judge_pair(photo, background, _sigma(photo), _sigma(background), usable, inside, cos)


def test_transmission_floor_is_two_films_at_their_brightest_reflection():
    """``T_min = mean_pol (1 - R_max)^2`` with ``R_max = 4 r / (1 + r)^2``, the peak of
    Airy's ``F s / (1 + F s)`` (``s = 1``, ``F = 4 r / (1 - r)^2``), from Fresnel's
    equations written in the test; the package's table is interpolated over 201 cosines."""
    from bubblefit.inverse import transmission_floor

    cos = np.linspace(0.2, 1.0, 17)
    r = fresnel_rs_rp(cos, 1.5)
    r_max = 4 * r / (1 + r) ** 2
    want = np.mean((1 - r_max) ** 2, axis=-1)
    np.testing.assert_allclose(transmission_floor(cos, 1.5), want, atol=2e-3)
    assert 0.72 < float(transmission_floor(np.array([1.0]), 1.5)[0]) < 0.73  # (1 - 0.148)^2


def test_right_pair_passes_and_swapped_pair_is_refused(pair):
    photo, back, _ = pair
    right = _judge(photo, back)
    assert right.refusal() is None
    assert right.dark_share == 0.0 and right.outside_share < 0.01
    swapped = _judge(back, photo)
    why = swapped.refusal()
    assert why is not None and "swapped" in why and "\n" not in why
    assert swapped.dark_share > 0.05 and swapped.swap_possible


def test_right_pairs_are_never_refused_over_noise_draws(pair):
    """The conservation floor holds under noise: 20 noise draws of the same right pair, and
    one with the photo a quarter stop darker than its background (the test takes the
    exposure ratio measured off the bubble), none refused."""
    photo, back, _ = pair
    from bubblefit.model.scene import shipped_envmap  # noqa: F401 - the fixture's scene is enough

    for seed in range(20):
        rng = np.random.default_rng(100 + seed)
        p = quantise_8bit(np.clip(photo, 0, None), rng, read=0.002)
        assert _judge(p, back).refusal() is None
    assert _judge(photo * 2 ** -0.25, back).refusal() is None


def test_a_sequence_checks_its_first_frame_before_any_fit(pair):
    """``fit-sequence`` resolves the disc on its first frame and checks the pair there
    (:func:`~bubblefit.inverse._plan.check_disc_pair`), at the photo's own resolution."""
    from bubblefit.errors import InputError
    from bubblefit.inverse import FitOptions, NoiseSettings
    from bubblefit.inverse import check_disc_pair

    photo, back, other = pair
    opts = FitOptions(noise=NoiseSettings(bits=8))
    assert check_disc_pair(photo, back, DISC, opts).refusal() is None
    with pytest.raises(InputError, match="look swapped"):
        check_disc_pair(back, photo, DISC, opts)
    with pytest.raises(InputError, match="does not show the photo's view"):
        check_disc_pair(photo, other, DISC, opts)


def test_background_of_another_scene_is_refused(pair):
    photo, _, other = pair
    check = _judge(photo, other)
    why = check.refusal()
    assert why is not None and "does not show the photo's view" in why
    assert check.outside_share > 0.5


def test_a_small_exposure_change_is_the_same_view(pair):
    _, back, _ = pair
    rng = np.random.default_rng(5)
    again = quantise_8bit(back * 1.06, rng)  # a 6 % longer exposure of the same backdrop
    from bubblefit.inverse import outside_mismatch

    off = np.ones(back.shape[:2], bool)
    share, n, ratio = outside_mismatch(again, back, _sigma(again), _sigma(back), off)
    assert share < 0.01 and n == off.sum()
    np.testing.assert_allclose(ratio, 1.06, atol=0.01)


def test_a_misfit_over_most_pixels_is_not_called_local():
    """All pixels outliers: the warning does not call the misfit local (no 'the rest are
    at 0'); with a pair the pre-fit test could not order, it asks about a swap."""
    from bubblefit.inverse import Misfit
    from bubblefit.inverse import verdict

    misfit = Misfit(chi2_nu=400.0, chi2_floor=300.0, chi2_inliers=0.0, outliers=1.0, chi2_capped=30.0)
    ok, warnings = verdict(converged=True, disc_found=True, bound_warnings=[], misfit=misfit, ok_chi2=3.0,
                           model_error=0.03, notes=[], swap_possible=True)
    text = " ".join(warnings)
    assert not ok and "local" not in text and "rest are at" not in text and "swapped" in text
    few = Misfit(chi2_nu=40.0, chi2_floor=30.0, chi2_inliers=1.2, outliers=0.05, chi2_capped=3.0)
    _, warnings = verdict(converged=True, disc_found=True, bound_warnings=[], misfit=few, ok_chi2=3.0,
                          model_error=0.03, notes=[])
    assert "the misfit is local" in " ".join(warnings)


def test_least_reflectance_matches_an_independent_airy_and_cie_y():
    """The least Y-weighted reflectance of a film (D65, flat spectrum) over thickness and
    angle, against Airy's formula and colour-science's CIE 1931 observer at 1 nm."""
    colour = pytest.importorskip("colour")
    from bubblefit.inverse import least_reflectance

    lam = np.arange(380.0, 781.0, 1.0)
    ybar = np.asarray(colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"][lam])[:, 1]
    s = np.asarray(colour.SDS_ILLUMINANTS["D65"][lam])
    w = s * ybar / np.sum(s * ybar)
    d = np.linspace(50.0, 600.0, 221)[:, None, None]
    cos = np.linspace(math.sqrt(1 - 0.96**2), 1.0, 24)[None, :, None]
    r = airy_reflectance(cos, 1.33, d, lam[None, None, :]).mean(axis=-1)  # (d, cos, lambda)
    want = float(np.min(r @ w))
    got = least_reflectance(50.0, 600.0, 0.96)
    assert got == pytest.approx(want, rel=0.08)


def test_exposure_range_holds_the_true_gain_and_not_an_absurd_one(pair):
    """On the rendered pair (gain 1, the courtyard map as rendered), 1 lies within the
    bounds; a fit's 95360 of a wrong, clipped map does not."""
    from bubblefit.inverse import exposure_doubt, exposure_range, least_reflectance, map_levels
    from bubblefit.inverse import LUMINANCE
    from bubblefit.io.images import read_image
    from bubblefit.model.scene import shipped_envmap

    photo, back, _ = pair
    inside, cos = _geometry()
    mask = inside & (cos > math.sqrt(1 - 0.96**2))
    y, b = photo[mask] @ LUMINANCE, back[mask] @ LUMINANCE
    median, mean = map_levels(read_image(shipped_envmap("courtyard")).pixels)
    lower, upper = exposure_range(float(y.mean()), float(np.maximum(y - b, 0).mean()), median, mean,
                                  least_reflectance(50.0, 2000.0, 0.96))
    assert lower < 1.0 < upper
    assert exposure_doubt(1.0, lower, upper) is None
    why = exposure_doubt(95360.0, lower, upper)
    assert why is not None and "clipped" in why and "not the one" in why


def test_an_8bit_studio_map_bounds_the_exposure_below_the_absurd(pair, tmp_path):
    """The shipped studio map saved as an 8-bit JPEG (mostly black, its lamps clipped at 1):
    the photo's brightness allows at most a gain of a few ten thousand, below the 95360 a
    fit of such a map reported; and reading the JPEG warns that it is 8-bit and clipped."""
    import warnings

    from bubblefit.cli.fit import load_envmap
    from bubblefit.inverse import exposure_range, least_reflectance, map_levels
    from bubblefit.inverse import LUMINANCE
    from bubblefit.io.images import read_image, write_image
    from bubblefit.model.scene import shipped_envmap

    jpeg = tmp_path / "studio.jpg"
    write_image(jpeg, np.clip(read_image(shipped_envmap("studio")).pixels, 0, 1))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = load_envmap(str(jpeg))
    assert any("8 bits per channel" in str(w.message) and "clipped" in str(w.message) for w in caught)
    photo, _, _ = pair
    inside, cos = _geometry()
    y = photo[inside & (cos > math.sqrt(1 - 0.96**2))] @ LUMINANCE
    median, mean = map_levels(np.asarray(env.pixels))
    _, upper = exposure_range(float(y.mean()), None, median, mean, least_reflectance(50.0, 2000.0, 0.96))
    assert upper < 95360.0


# ---------------------------------------------------------------------------------------
# The command line: refused in one line, exit 2, before the fit, nothing written
# ---------------------------------------------------------------------------------------


def _write(tmp_path, name, img):
    from bubblefit.io.images import write_image

    path = tmp_path / name
    write_image(path, np.clip(img, 0, 1), bit_depth=8)
    return path


def _fit(tmp_path, photo, background):
    from bubblefit.model.scene import shipped_envmap

    out = tmp_path / "out.json"
    proc = subprocess.run([sys.executable, "-m", "bubblefit", "fit", str(photo), "--background", str(background),
                           "--envmap", str(shipped_envmap("courtyard")), "--json", str(out),
                           "--disc", ",".join(str(v) for v in DISC)],  # a 48 px photo's rim is too small to find
                          capture_output=True, text=True, timeout=600)
    return proc, out


def _assert_refused(proc, out, phrase: str) -> None:
    """Exit 2, one error line holding ``phrase``, no traceback, no JSON written, no search run."""
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("bubblefit: error")]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and phrase in lines[0] and "Traceback" not in proc.stderr
    assert not out.exists() and "searching" not in proc.stderr


@pytest.mark.slow
def test_fit_refuses_swapped_files_before_the_fit(pair, tmp_path):
    photo, back, _ = pair
    p, b = _write(tmp_path, "photo.png", photo), _write(tmp_path, "background.png", back)
    _assert_refused(*_fit(tmp_path, b, p), "look swapped")


@pytest.mark.slow
def test_fit_refuses_a_background_of_another_scene(pair, tmp_path):
    photo, _, other = pair
    p, o = _write(tmp_path, "photo.png", photo), _write(tmp_path, "other.png", other)
    _assert_refused(*_fit(tmp_path, p, o), "does not show the photo's view")
