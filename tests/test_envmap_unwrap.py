"""The mirror-ball unwrap (``bubblefit envmap``, :func:`bubblefit.capture.probe.unwrap_mirror_ball`)
against closed forms.

The truth is a radiance *function* of direction, not a map: a photo of a perfect mirror
sphere is rendered from it analytically in tests/helpers.py (the reflection law
``r = d - 2 (d.n) n`` at the ball point of each of 4 x 4 samples per pixel, for an
orthographic and for a pinhole camera), and the unwrapped map is compared with the
function at its texel centres (or its exact texel means), in docs/design.md's map
convention written in the test. Nothing of the package but the unwrap is used.
"""

from __future__ import annotations

import numpy as np
import pytest

from bubblefit.capture import ball, probe
from helpers import (harmonic_radiance, mirror_ball_photo, mirror_ball_photo_perspective, texel_centres,
                     texel_mean_directions)

A = np.array([0.3, -0.2, 0.25])     # L(w) = C (1 + A . w): a sky brighter towards +x, +z and down
C = np.array([1.0, 0.8, 0.6])
SIZE, CX, CY, R = 160, 81.3, 78.6, 60.0  # the ball off the pixel grid


def _sky(d):
    return harmonic_radiance(d, A, C)


def _photo(distance):
    if distance is None:
        return mirror_ball_photo(_sky, SIZE, CX, CY, R)
    return mirror_ball_photo_perspective(_sky, SIZE, CX, CY, R, distance)


def _back_angle(dirs):
    """Angle (radians) of each direction from -z, straight behind the ball."""
    return np.arccos(np.clip(-dirs[..., 2], -1.0, 1.0))


def _photo_error_bound(beta, distance):
    """Bound on ``|unwrapped - L(w)| / max(C)`` at a texel ``beta`` radians from -z.

    The unwrap reads the photo bilinearly at the ball point that reflects ``w``. The photo
    pixel is the mean of ``g(x, y) = L(d(x, y))`` over the pixel (4 x 4 samples), whose
    error against ``g`` at the centre is ``h^2 / 24 |g''|`` per axis, and bilinear
    interpolation adds ``h^2 / 8 |g''|`` per axis: ``(|g_xx| + |g_yy|) / 6`` with
    ``h = 1 / R`` in ball radii. With ``g = C (1 + A . d)`` and the reflected direction
    ``d = (2 x n_z, 2 y n_z, 2 n_z^2 - 1)``, ``n_z = sqrt(1 - x^2 - y^2)``, the second
    derivatives are at most ``|d_xx| <= sqrt(6^2 + 2^2 + 4^2) / n_z^3 < 7.5 / n_z^3`` (and
    the same for y), so ``err <= 2.5 |A| / (n_z^3 R^2)``.

    ``n_z`` is the cosine of the incidence at the ball point, taken one pixel rim-ward of
    it: ``rho = sin(theta_i) + 1 / R`` with ``theta_i = (pi - beta) / 2`` (the ray turns by
    ``pi - beta``). A pinhole camera at ``distance`` radii sees the ball under the
    half-angle ``alpha = asin(1 / distance)``, which tilts the incidence by at most alpha
    (``theta_i <= (pi - beta + alpha) / 2``); its pixels are smaller on the ball than the
    orthographic camera's. Where the rim-ward pixel leaves the ball there is no bound
    (``inf``): the rim shows those directions infinitely compressed.
    """
    alpha = 0.0 if distance is None else np.arcsin(1.0 / distance)
    theta_i = np.clip(0.5 * (np.pi - beta + alpha), 0.0, 0.5 * np.pi)
    rho = np.sin(theta_i) + 1.0 / R
    nz = np.sqrt(np.clip(1.0 - rho**2, 0.0, None))
    with np.errstate(divide="ignore"):
        return np.where(rho < 1.0, 2.5 * np.linalg.norm(A) / (nz**3 * R**2), np.inf)


@pytest.mark.parametrize("distance", [None, 6.0])
@pytest.mark.parametrize("height", [32, 64])
def test_point_sampled_unwrap_is_the_sky(distance, height):
    """One direction per texel (``supersample=1``): every valid texel equals the sky at its
    centre within the photo's own resampling error (``_photo_error_bound``): about 2e-4 of
    the sky facing the camera and growing as 1 / n_z^3 towards the masked rim."""
    pm = probe.unwrap_mirror_ball(_photo(distance), ball.Circle(CX, CY, R), height=height, distance=distance,
                                  fill=False, supersample=1)
    dirs = texel_centres(height, 2 * height)
    err = np.abs(pm.pixels - _sky(dirs)).max(axis=-1) / C.max()
    bound = _photo_error_bound(_back_angle(dirs), distance)
    judged = pm.valid & np.isfinite(bound)
    assert pm.valid.mean() > 0.95 and judged.sum() > 0.9 * pm.valid.sum()
    worst = np.argmax(np.where(judged, err / bound, 0.0))
    assert np.all(err[judged] <= bound[judged]), (np.degrees(_back_angle(dirs)).ravel()[worst],
                                                  err.ravel()[worst], bound.ravel()[worst])
    # and the sky facing the camera (> 90 degrees from -z) to 3e-4 of its brightness
    front = pm.valid & (_back_angle(dirs) > 0.5 * np.pi)
    assert err[front].max() < 3e-4


@pytest.mark.parametrize("height", [16, 32, 64])
def test_box_filtered_unwrap_is_the_texel_mean(height):
    """With its default sub-samples per texel the unwrap is a box filter: a linear sky
    gives the sky at the texel's mean direction (closed form, ``texel_mean_directions``),
    not at its centre (they differ by up to 1.2 % of the sky at the poles of a 32-row map),
    within the photo's resampling error at the texel's rim-ward edge and the sub-samples'
    midpoint error ``|A| D^2 / 8`` (D the texel's angular size). The two pole rows cover
    ``theta in [0, D / 2]``, where the ``sin(theta)`` weight moves the mean to about D / 3
    while ``s`` sub-samples in theta (half of them clipped onto the pole, with no weight)
    put it at ``D / 4`` for ``s = 2``: a first-order error of at most ``|A| D / (6 s)``."""
    pm = probe.unwrap_mirror_ball(_photo(None), ball.Circle(CX, CY, R), height=height, fill=False)
    dirs = texel_centres(height, 2 * height)
    mean = texel_mean_directions(height, 2 * height)
    step = np.pi / (height - 1)
    got = pm.pixels
    err = np.abs(got - C * (1.0 + mean @ A)[..., None]).max(axis=-1) / C.max()
    bound = _photo_error_bound(_back_angle(dirs) - step, None) + np.linalg.norm(A) * step**2 / 8
    bound[[0, -1]] += np.linalg.norm(A) * step / (6 * pm.info["supersample"])
    judged = pm.valid & np.isfinite(bound)
    assert judged.sum() > 0.85 * pm.valid.sum()
    assert np.all(err[judged] <= bound[judged]), float(np.max(err[judged] / bound[judged]))
    # the centre value is measurably not what a box filter gives near the poles
    centre_err = np.abs(got - _sky(dirs)).max(axis=-1) / C.max()
    assert centre_err[judged].max() > 2 * err[judged].max() or height == 64


@pytest.mark.parametrize("rotation", [0.0, 0.7])
def test_a_sun_lands_at_its_direction(rotation):
    """A cap of 12 degrees around a known direction ``s``, 20 times the sky: the unwrapped
    map's excess (over the uniform sky, weighted by the texels' solid angles) is centred on
    ``s`` (or on ``R_y(-rotation) s`` for a rotated map: the map's ``w`` reads the camera's
    ``R_y(rotation) w``) within a texel, and carries the cap's power
    ``19 * 2 pi (1 - cos 12 deg)`` within 6 %: the box filter keeps power, and the cap's
    outline cuts through 8-bit-free pixels whose area the photo integrates."""
    s = np.array([0.55, 0.35, 0.4])
    s /= np.linalg.norm(s)
    cap = np.cos(np.radians(12.0))

    def sky(d):
        return np.where((d @ s >= cap)[..., None], 20.0, 1.0) * np.ones(3)

    height = 64
    photo = mirror_ball_photo(sky, SIZE, CX, CY, R, ss=8)
    pm = probe.unwrap_mirror_ball(photo, ball.Circle(CX, CY, R), height=height, rotation=rotation, fill=False)
    dirs = texel_centres(height, 2 * height)
    # solid angle of each texel: the band's (closed form) over its columns
    i = np.arange(height)
    t0 = np.clip((i - 0.5) / (height - 1), 0, 1) * np.pi
    t1 = np.clip((i + 0.5) / (height - 1), 0, 1) * np.pi
    omega = ((np.cos(t0) - np.cos(t1)) * np.pi / height)[:, None] * np.ones((1, 2 * height))
    excess = (pm.pixels[..., 1] - 1.0) * omega * pm.valid
    centre = (excess[..., None] * dirs).sum(axis=(0, 1))
    centre /= np.linalg.norm(centre)
    c, sn = np.cos(rotation), np.sin(rotation)
    ry = np.array([[c, 0.0, sn], [0.0, 1.0, 0.0], [-sn, 0.0, c]])  # right-handed rotation about +y
    expect = ry.T @ s
    assert np.degrees(np.arccos(np.clip(centre @ expect, -1, 1))) < np.degrees(np.pi / (height - 1)), centre
    power = 19.0 * 2 * np.pi * (1 - cap)
    assert abs(excess.sum() / power - 1) < 0.06, excess.sum() / power
