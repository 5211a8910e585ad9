"""The forward model a fit uses: the physical model fitted, and ``model = "auto"``.

A photo of a physical film (Fresnel per polarisation, Airy film, internal bounces) is
rendered at 48 px over a textured background, with noise and 8-bit sRGB. Fitted with the
physical model, the thickness comes back within its error bars and ``r_d`` is a fitted
parameter (with a standard error), while ``t`` and ``r_s``, which Fresnel sets, are held.
With ``auto`` the fit keeps whichever model explains the photo better, and says so.
"""

from __future__ import annotations

import numpy as np
import pytest

from test_fit import DISC, _background, _opts, _quantise, _render


@pytest.fixture(scope="module")
def physical_photo(small_courtyard):
    from bubblefit.lighting.envmap import EnvMap

    env = EnvMap.from_array(small_courtyard)
    rng = np.random.default_rng(23)
    bg = _background(rng)
    photo = _quantise(_render(env, bg, {"roughness": 0.06, "thickness_nm": 480.0, "r_d": 0.004},
                              model="physical"), rng)
    return env, photo, _quantise(bg, rng)


def test_physical_model_fit(physical_photo):
    from bubblefit.inverse.fit import fit_photo

    env, photo, bg = physical_photo
    res = fit_photo(photo, env, options=_opts(model="physical"), background=bg)
    assert res.model == "physical" and res.converged, res.message
    err = abs(res.params["thickness_nm"] - 480.0)
    assert err < 5.0 and err < 4 * res.stderr["thickness_nm"] + 1.0, (res.params, res.stderr)
    held = dict(res.held)
    assert "t" in held and "r_s" in held and "r_d" not in held
    assert res.stderr["r_d"] is not None and np.isfinite(res.stderr["r_d"]) and res.stderr["r_d"] > 0
    assert "(held" in [l for l in res.report().splitlines() if l.startswith("t ")][0]


def test_auto_keeps_the_model_that_explains_the_photo(physical_photo):
    from bubblefit.inverse.fit import fit_photo

    env, photo, bg = physical_photo
    paper = fit_photo(photo, env, options=_opts(model="paper"), background=bg)
    auto = fit_photo(photo, env, options=_opts(model="auto"), background=bg)
    assert "model auto" in auto.message
    if paper.converged and paper.chi2_floor <= 3.0:
        assert auto.model == "paper"  # explained: no second fit
    else:
        assert auto.chi2_floor <= paper.chi2_floor + 1e-9
        assert auto.model == ("physical" if auto.chi2_floor < paper.chi2_floor else "paper")
    assert abs(auto.params["thickness_nm"] - 480.0) < 10.0
