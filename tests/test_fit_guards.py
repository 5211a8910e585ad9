"""A fit reports no value outside the range it searched, and refuses a photo in which
the disc detector finds no bubble."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy import ndimage as ndi

from bubblefit.errors import InputError


def _table(free):
    from bubblefit.inverse import ParameterTable

    return ParameterTable(free=tuple(free), held=())


def test_a_thickness_past_the_search_is_reported_at_its_bound():
    """4.4 nm from a 50-2000 nm search comes back as 50 nm, with a warning; a value inside,
    and a held one, are left alone."""
    from bubblefit.inverse import clamp_to_range

    keys = ("thickness_nm", "top_nm", "bottom_nm")
    got, warn = clamp_to_range({"thickness_nm": 4.4, "t": 0.97}, _table(["thickness_nm"]), (50.0, 2000.0), keys)
    assert got == {"thickness_nm": 50.0, "t": 0.97}
    assert len(warn) == 1 and "4.4" in warn[0] and "bound 50" in warn[0]
    got, warn = clamp_to_range({"top_nm": 120.0, "bottom_nm": 2412.0}, _table(["top_nm", "bottom_nm"]),
                               (50.0, 2000.0), keys)
    assert got == {"top_nm": 120.0, "bottom_nm": 2000.0} and len(warn) == 1
    got, warn = clamp_to_range({"thickness_nm": 4.4}, _table([]), (50.0, 2000.0), keys)
    assert got == {"thickness_nm": 4.4} and warn == []


def test_verdict_of_a_clamped_thickness_is_not_ok():
    from bubblefit.inverse import Misfit
    from bubblefit.inverse import clamp_to_range, verdict

    _, warn = clamp_to_range({"thickness_nm": 4.4}, _table(["thickness_nm"]), (50.0, 2000.0), ("thickness_nm",))
    fields = Misfit.__dataclass_fields__
    misfit = Misfit(**{k: (1.0 if k != "outliers" else 0.0) for k in fields})
    ok, warnings = verdict(converged=True, disc_found=True, bound_warnings=warn, misfit=misfit, ok_chi2=3.0,
                           model_error=0.03, notes=[])
    assert not ok and warn[0] in warnings


def test_a_photo_without_a_bubble_is_refused_without_a_background_photo():
    """A smooth textured photo with nothing round in it and no background photo: the robust
    detector finds no rim, and the fit refuses rather than fitting the simpler detector's
    guess; with the disc given, it is taken."""
    from bubblefit.inverse import resolve_disc
    from bubblefit.inverse import FitOptions

    rng = np.random.default_rng(3)
    photo = ndi.gaussian_filter(rng.uniform(0.1, 0.7, (96, 128, 3)), (6, 6, 0))
    with pytest.raises(InputError, match="--disc"):
        resolve_disc(photo, None, FitOptions())
    disc, warn = resolve_disc(photo, None, FitOptions(disc=(64.0, 48.0, 30.0)), given=(64.0, 48.0, 30.0))
    assert disc == (64.0, 48.0, 30.0) and warn == []


@functools.lru_cache(maxsize=2)
def _grey_film(background: str):
    """A 40 x 40 film rendered without interference (a thick film) at camera gain 2.5,
    noise-free, over a background photo (black, not scaled by the gain: ``"photo"``) or
    the map (scaled: ``"env"``): ``(setup, options, env)`` of its fit."""
    import bubblefit as bf
    from bubblefit.inverse import FitOptions
    from bubblefit.inverse._setup import setup

    scene = bf.Scene.from_dict({
        "camera": {"width": 40, "height": 40, "disc": [20, 20, 15]},
        "bubble": {"thickness_nm": 600.0, "t": 0.972, "f": 0.3, "roughness": 0.02},
        "lighting": {"envmap": "courtyard.exr", "background": "black" if background == "photo" else "envmap"},
        "effects": {"interference": "off"}})
    env = scene.load_envmap()
    photo = 2.5 * np.asarray(bf.render_scene(scene), np.float64)
    back = np.zeros_like(photo) if background == "photo" else None
    opts = FitOptions(disc=(20, 20, 15), view=bf.resolve_view(fov_deg=0, width=40, height=40),
                      effects=(("interference", "off"),), model="paper")
    return setup(photo, env, opts, back, None, scene, None), opts, env


def test_a_grey_film_starts_from_its_least_squares_exposure():
    """A film rendered without interference (a thick film) has no thickness search to set
    the camera gain. The start is the gain's least-squares value, exact for a render
    that is affine in it: on a noise-free photo at gain 2.5 it is 2.5 to float32's rounding
    of the render (relative 1e-5), with a background photo (not scaled by the gain) and
    with the map as the background (scaled)."""
    from bubblefit.inverse.search import grey_exposure

    for background in ("photo", "env"):
        st, opts, env = _grey_film(background)
        got = grey_exposure(st.level(1, opts), st.table, dict(st.vals, exposure=1.0), env)
        assert got == pytest.approx(2.5, rel=1e-4), (background, got)


def test_the_local_solve_leaves_a_start_far_off_in_the_gain():
    """From gain 1 on the grey film at gain 2.5 (no least-squares start), the local solve
    reaches 2.5: every residual is then far out on the pseudo-Huber's linear arm, where
    the robust residual's Gauss-Newton step is twice the plain one (and the plain one,
    linear in the log of the gain, overshoots too), so the trust region rejects the first
    eight trial steps; six rejections in a row had stopped the solve where it started. It
    ends within the statistical stop's fifth of a standard error of the gain (the photo is
    noise-free, so that error is the noise model's), plus float32's rounding of the render
    (1e-5)."""
    from bubblefit.inverse._lm import STOP_DECREMENT
    from bubblefit.inverse._local import solve_local

    st, opts, env = _grey_film("photo")
    assert st.table.free == ("exposure",)
    sol = solve_local(st.lev_fit, st.table, opts.solver, dict(st.vals, exposure=1.0), env)
    gain = sol.values["exposure"]
    jac = sol.jacobian
    se = gain * math.sqrt(float(np.linalg.inv(jac.T @ jac)[0, 0]))  # the log coordinate's error times d gain / d z
    assert sol.successful and abs(gain - 2.5) <= math.sqrt(STOP_DECREMENT) * se + 2.5e-5, (gain, se, sol.steps)
