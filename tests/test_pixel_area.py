"""Pixel area: ``[camera] samples_per_pixel`` box-filters each pixel (bubblefit.model.geometry.pixel_offsets).

The check is exact by construction: a 4x4 stratified render of W x H pixels samples the
same points as a 4W x 4H render (disc scaled by 4) samples at its pixel centres, so the
former must equal the 4x4 block average of the latter, at the bubble's edge (where
point sampling aliases) as everywhere else.
"""

from __future__ import annotations

import numpy as np
import pytest

from bubblefit.errors import InputError
from bubblefit.model.geometry import pixel_offsets
from bubblefit.model.scene import Scene, render_scene


def _scene(w, h, disc, spp):
    return Scene.from_dict({
        "camera": {"width": w, "height": h, "disc": list(disc), "samples_per_pixel": spp},
        "bubble": {"thickness_nm": 420.0, "roughness": 0.05},
        "lighting": {"point_lights": [{"direction": [0.3, 0.5, 1.0], "radiance": [2.0, 2.0, 2.0]}],
                     "background": "black"},
        # every effect pinned: ``auto`` may decide per pixel, and differently at another size
        "effects": {"model": "physical", "spectral": {"method": "uniform", "samples": 16}, "filtering": "mirror",
                    "interference": "airy", "bounces": 2, "diffuse": True, "front_reflection": True,
                    "rear_reflection": True},
    })


def test_offsets_are_stratified_box_samples():
    o = pixel_offsets(16)
    assert o.shape == (16, 2)
    np.testing.assert_allclose(o.mean(axis=0), 0.0, atol=1e-15)
    np.testing.assert_allclose(np.unique(o[:, 0]), [-0.375, -0.125, 0.125, 0.375])
    np.testing.assert_allclose(pixel_offsets(1), [[0.0, 0.0]])
    with pytest.raises(ValueError):
        pixel_offsets(8)


def test_supersampled_edge_equals_box_average_of_larger_render():
    w = h = 12
    small = render_scene(_scene(w, h, (6.3, 5.8, 4.7), 16))
    big = render_scene(_scene(4 * w, 4 * h, (4 * 6.3, 4 * 5.8, 4 * 4.7), 1))
    boxed = big.reshape(h, 4, w, 4, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(small, boxed, rtol=2e-4, atol=2e-6)
    point = render_scene(_scene(w, h, (6.3, 5.8, 4.7), 1))
    # Not vacuous: at the rim point sampling differs from the box average.
    assert np.abs(point - boxed).max() > 20 * np.abs(small - boxed).max()


def test_samples_per_pixel_must_be_square():
    with pytest.raises(InputError, match="square"):
        _scene(8, 8, (4, 4, 3), 8)


def test_solve_renders_the_rim_blocks_as_the_photo_averages_them():
    """A photo's block is the mean of its pixels: a draining film's disc rendered 3 times
    finer and block-averaged, fitted on the blocks with the disc free, gives back its
    radius (a constant film's solve keeps one ray a block: ``solve_program``).

    The local solve renders the blocks at the rim with the 2 x 2 Gauss-Legendre rule
    (``inverse._programs.solve_pixels``, ``gauss_offsets(4)``), which averages the
    radiance's curvature across a block exactly; the photo's blocks here are means of
    3 x 3 point samples, another rule, and the disc's edge crosses a few blocks, so model
    and photo still differ a little (0.015 px in the radius). The
    refined radius must lie well inside the disc's Type B error, which a fit states as
    ``FitOptions.disc_model_error`` of the radius; one ray per block sets it 0.18 px
    (0.5 % of the radius) short, more than twice that.
    """
    import jax.numpy as jnp
    from scipy import ndimage as ndi

    from bubblefit.inverse._local import solve_local
    from bubblefit.inverse._observation import make_level
    from bubblefit.inverse._options import FitOptions, SolverSettings
    from bubblefit.inverse._parameters import ParameterTable
    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.lighting.filtering import FilterConfig
    from bubblefit.model.effects import Effects
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.model.render import RenderConfig, render
    from bubblefit.optics.spectral import spectral_basis

    k, w, h, disc = 3, 36, 32, (17.3, 15.6, 12.4)  # the blocks; the photo k times finer
    rng = np.random.default_rng(5)
    env = EnvMap.from_array(ndi.gaussian_filter(rng.uniform(0.2, 1.0, (32, 64, 3)), (2, 2, 0)).astype(np.float32))
    bg = ndi.gaussian_filter(rng.uniform(0.1, 0.5, (k * h, k * w, 3)), (4, 4, 0)).astype(np.float32)
    fx = Effects(model="physical", interference="airy", filtering=FilterConfig("mirror"), diffuse=False,
                 spectral=spectral_basis("uniform", 8), background="photo", thickness="drainage")
    fine = RenderConfig(effects=fx, camera=OrthographicCamera(k * w, k * h, *(k * v for v in disc)))
    truth = dict(t=0.972, split=1.0, roughness=0.0, thickness_nm=420.0, top_nm=300.0, bottom_nm=600.0,
                 exponent=1.0, exposure=1.0, rotation_deg=0.0, n_film=1.4, f=0.0, disc_x=0.0, disc_y=0.0, disc_r=0.0)
    table = ParameterTable(free=("disc_x", "disc_y", "disc_r"), thickness_model="drainage")
    params = table.render_params({n: jnp.float32(v) for n, v in truth.items()})
    photo = np.asarray(render(params, fine, env, jnp.asarray(bg)), np.float64)
    lev = make_level(k, fine, photo, np.full(photo.shape, 0.004), bg, np.zeros(photo.shape[:2], bool), 0.96)
    sol = solve_local(lev, table, SolverSettings(), truth, env)
    radius = k * disc[2]
    error_px = sol.values["disc_r"] * radius
    assert abs(error_px) < 0.5 * FitOptions().disc_model_error * radius, error_px


def test_solve_rays_in_one_list_equal_each_part_rendered_with_its_own_rays():
    """The local solve renders every block's rays in one list (``solve_pixels``' rays,
    ``render_pixels`` with each ray's count) and averages them per block (``block_means``):
    the same values as each part rendered with its own ``samples_per_pixel``, the pixel
    footprint of a rim ray (1/3 of its block per axis) included. Besides float32 rounding
    of sums of 9 terms of order 1, a footprint's filtered lookup varies with the rays beside
    it in its chunk (:func:`~bubblefit.lighting.envmap.lookup_parallelogram` reads the
    footprints of a cut in blocks): a centre ray among rim rays in a chunk of 60 read 1.8e-5
    off the same ray in a chunk of its own kind (0.41130 against 0.41132), so the tolerance
    is 5e-5."""
    import jax.numpy as jnp
    from dataclasses import replace
    from scipy import ndimage as ndi

    from bubblefit.inverse._observation import make_level
    from bubblefit.inverse._programs import block_means, solve_pixels
    from bubblefit.lighting.envmap import EnvMap
    from bubblefit.lighting.filtering import FilterConfig
    from bubblefit.model.effects import Effects
    from bubblefit.model.geometry import OrthographicCamera
    from bubblefit.model.render import Params, RenderConfig, render_pixels
    from bubblefit.optics.spectral import spectral_basis

    k, w, h = 3, 14, 12
    rng = np.random.default_rng(3)
    env = EnvMap.from_array(ndi.gaussian_filter(rng.uniform(0.2, 1.0, (32, 64, 3)), (1, 1, 0)).astype(np.float32))
    bg = rng.uniform(0.1, 0.5, (k * h, k * w, 3)).astype(np.float32)
    fx = Effects(model="physical", interference="airy", filtering=FilterConfig("mirror"), diffuse=False,
                 spectral=spectral_basis("uniform", 4), background="photo")
    cfg = RenderConfig(effects=fx, camera=OrthographicCamera(k * w, k * h, 20.0, 17.5, 15.0), pixel_footprint=True)
    photo = np.full((k * h, k * w, 3), 0.3)
    lev = make_level(k, cfg, photo, np.full(photo.shape, 0.004), bg, np.zeros(photo.shape[:2], bool), 0.96)
    px = solve_pixels(lev, 64, 9, rule="box")
    assert px.samples == 9 and px.rays[0].shape[0] > 1  # rim blocks of 9 rays, several chunks
    q, p = px.pixels, Params.make(thickness=420.0, roughness=0.0)
    cfg1 = q.padded.cfg
    rays = [np.asarray(a).reshape(-1) for a in px.rays]
    one = np.asarray(block_means(render_pixels(p, cfg1, env, q.padded.bg, *px.rays[:4]), rays[4], rays[5], q.y.shape[0]))
    centre = np.asarray(render_pixels(p, cfg1, env, q.padded.bg, q.rows, q.cols, q.idx))
    boxed = np.asarray(render_pixels(p, replace(cfg1, samples_per_pixel=9), env, q.padded.bg, q.rows, q.cols, q.idx))
    at_rim = np.bincount(rays[4], weights=rays[5] > 0, minlength=q.y.shape[0]) == 9  # blocks with 9 rays of weight
    assert 0 < at_rim.sum() < q.flat.size
    n = q.flat.size  # the blocks that pad the list take no ray: 0, at weight 0
    np.testing.assert_allclose(one[:n], np.where(at_rim[:, None], boxed, centre)[:n], rtol=0, atol=5e-5)
    assert not one[n:].any() and not np.asarray(q.w)[n:].any()
    # not vacuous: the rim's centre rays differ from their blocks' means
    assert np.abs(centre - boxed)[at_rim].max() > 10 * 5e-5


def test_gauss_offsets_average_a_cubic_over_the_box_exactly():
    """The 2 x 2 Gauss-Legendre rule (``gauss_offsets(4)``) gives the box averages of
    ``x^2`` (1/12), ``x^2 y^2`` (1/144) and ``x^3`` (0) to float64 rounding; the 3 x 3
    stratified centres give ``x^2`` as ``(1 - 1/9) / 12``, the curvature term they leave."""
    from bubblefit.model.geometry import gauss_offsets

    o, w = gauss_offsets(4)
    assert o.shape == (4, 2) and abs(w.sum() - 1.0) < 1e-15
    y, x = o[:, 0], o[:, 1]
    np.testing.assert_allclose([w @ x**2, w @ (x**2 * y**2), w @ x**3, w @ x], [1 / 12, 1 / 144, 0.0, 0.0],
                               rtol=1e-13, atol=1e-16)
    s = pixel_offsets(9)[:, 1]
    np.testing.assert_allclose(np.mean(s**2), (1 - 1 / 9) / 12, rtol=1e-13)
    with pytest.raises(ValueError):
        gauss_offsets(8)
