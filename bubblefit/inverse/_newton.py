"""Newton's rings: the radius of a lens on a plate, fitted to a colour photo of the gap.

A spherical surface of radius ``R`` touching a flat plate leaves the gap
``h(r) = R - sqrt(R^2 - r^2) + h0`` at the distance ``r`` from the contact point
``(cx, cy)`` (``h0``: an offset at contact, dust or a pressed lens; ``h >= 0``). The
parameters ``(R, cx, cy, h0, g)`` are fitted to the pixels' colours by Levenberg-Marquardt,
started from a per-pixel map: the centre of the thinnest pixels, and ``R``, ``h0`` from a
straight line of the map against ``r^2`` (``h ~ h0 + r^2 / (2 R)``) where the map is
below half the searched range (:func:`colour_start`); where that map is ambiguous (one
wavelength: every dark ring looks like the contact point), also from the rings' symmetry
and period without colour (:func:`rings_centre`, :func:`rings_period`). With them, a grey
stray reflectance (light that does not interfere) and the lamp's smooth envelope across the
field (:func:`lamp_envelope`) where the rings span enough fringes to fix it. With a calibrated
response that states its errors, the rings' order (the contact offset's, one fringe either
way) is tested
(:func:`bubblefit.inverse._planar_lm.fit_order`).

References
----------
M. Born and E. Wolf, *Principles of Optics*, 7th ed., sec. 7.5.3 (Newton's rings);
D. W. Marquardt, J. SIAM 11, 431-441 (1963).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._planar_lm import ModelFit, fit_colours, fit_order
from ._uncertainty import widened_over_film
from ..model.planar_scene import ENVELOPE_DEFAULT, STRAY_DEFAULT

__all__ = ["ENVELOPE_TERMS", "aliased_pixels", "colour_start", "envelope_coordinates", "fit_newton",
           "lamp_envelope", "lost_rings_warning", "newton_gap", "newton_gap_gradient", "pixel_mean", "rings_centre",
           "rings_period"]


def newton_gap(r_um, radius_um, h0_nm):
    """Gap (nm) at ``r_um`` from the contact point of a lens of radius ``radius_um`` on a plate."""
    r2 = jnp.minimum(r_um * r_um, 0.999999 * radius_um * radius_um)
    sag = r2 / (radius_um + jnp.sqrt(radius_um * radius_um - r2))  # = R - sqrt(R^2 - r^2), without cancellation
    return jnp.maximum(1000.0 * sag + h0_nm, 0.0)


def newton_gap_gradient(dx_um, dy_um, radius_um):
    """``(dh/dx, dh/dy)`` (nm per um) of :func:`newton_gap` at ``(dx, dy)`` from the contact
    point: ``dh/dr = r / sqrt(R^2 - r^2)`` (``~ r / R`` near contact; Born and Wolf sec.
    7.5.3), along ``(dx, dy) / r``."""
    r2 = jnp.minimum(dx_um * dx_um + dy_um * dy_um, 0.999999 * radius_um * radius_um)
    slope = 1000.0 / jnp.sqrt(radius_um * radius_um - r2)
    return dx_um * slope, dy_um * slope


def pixel_mean(fwd, h, sin2, stray, gx, gy, pitch_um: float, lo: float, hi: float):
    """The mean colour (P, 3) of the gap's reflectance over each pixel's square (side
    ``pitch_um`` on the film) where the gap varies linearly across it: ``h`` (P,) at the
    pixel's centre, ``(gx, gy)`` (P,) its gradient (nm per um), seen at ``sin2`` with the
    stray reflectance ``stray`` (:meth:`~bubblefit.inverse.planar.PlanarForward.rgb`).

    The camera integrates the light over its pixel's box aperture: the image is the scene
    convolved with ``rect(x/p) rect(y/p)``, whose transfer function is ``sinc(f_x p)
    sinc(f_y p)`` (J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed., sec. 2.1 and
    Table 2.1, rect <-> sinc; sec. 6.2's detector aperture). For a two-beam film of phase
    ``delta`` linear across the pixel, ``<cos delta> = cos(delta_c) sinc(g_x p/2) sinc(g_y p/2)``
    (``g = grad delta``, ``sinc x = sin x / x``): the fringes' visibility falls as they
    approach the pixel pitch. The Airy sum's harmonics fall each by its own sinc, in closed
    form (:func:`bubblefit.optics.film.box_airy_reflectance`): one evaluation per pixel.
    Where the gap is held at ``lo`` or ``hi`` (the contact's flat, the range's end) the
    pixel is taken as flat."""
    inside = (h > lo) & (h < hi)
    sx = jnp.where(inside, gx * pitch_um, 0.0)
    sy = jnp.where(inside, gy * pitch_um, 0.0)
    colour = _per_pixel(lambda hh, ax, ay, b: fwd.rgb(hh, sin2, b[..., None], span=(ax, ay)))
    return colour(h, sx, sy, jnp.broadcast_to(stray, jnp.shape(h)))


def _per_pixel(colour):
    """``colour(h, sx, sy, b)`` (P,) x 4 -> (P, 3) with the forward derivative of a function
    whose pixels depend each on its own four values alone: the Jacobian of the
    pixels' colours is diagonal in the pixels, so each pixel's four partial derivatives
    (one forward pass per input, batched; the stray ``b`` enters linearly and its pass
    touches only the sum) times the inputs' tangents is the derivative along any tangent.
    A fit's ``jax.jacfwd`` then costs four passes through the reflectance whatever the
    number of its parameters, rather than one per parameter (the chain rule; A. Griewank
    and A. Walther, *Evaluating Derivatives*, 2nd ed., SIAM 2008, sec. 3.1)."""

    @jax.custom_jvp
    def f(h, sx, sy, b):
        return colour(h, sx, sy, b)

    @f.defjvp
    def f_jvp(primals, tangents):
        h, sx, sy, b = primals
        one, zero = jnp.ones_like(h), jnp.zeros_like(h)
        basis = (jnp.stack([one, zero, zero]), jnp.stack([zero, one, zero]), jnp.stack([zero, zero, one]))
        out, parts = jax.vmap(lambda th, tx, ty: jax.jvp(lambda a, c, d: colour(a, c, d, b), (h, sx, sy),
                                                        (th, tx, ty)), out_axes=(None, 0))(*basis)
        _, db = jax.jvp(lambda bb: colour(h, sx, sy, bb), (b,), (one,))
        tan = parts[0] * tangents[0][:, None] + parts[1] * tangents[1][:, None] + parts[2] * tangents[2][:, None]
        return out, tan + db * tangents[3][:, None]

    return f


#: Fewest pixels per fringe the fit models: below 2 (Nyquist), the sampled rings alias
#: (Goodman, *Introduction to Fourier Optics*, sec. 2.4, the sampling theorem).
MIN_FRINGE_PX = 2.0


def aliased_pixels(gx, gy, pitch_um: float, fringe_nm: float) -> np.ndarray:
    """Pixels whose fringes repeat in fewer than :data:`MIN_FRINGE_PX` pixels: the gap
    changes by more than ``fringe_nm / MIN_FRINGE_PX`` across one pixel (``|grad h| p``)."""
    slope = np.hypot(np.asarray(gx, np.float64), np.asarray(gy, np.float64))
    return slope * pitch_um > fringe_nm / MIN_FRINGE_PX


def _circle_spread(x, y, value, cx: float, cy: float, width: float) -> float:
    """Within-circle variance of ``value`` about ``(cx, cy)``: the sum over rings of width
    ``width`` of the squared deviations from each ring's mean (zero for circular symmetry)."""
    k = (np.hypot(x - cx, y - cy) / width).astype(np.int64)
    n = np.bincount(k)
    s1 = np.bincount(k, value)
    s2 = np.bincount(k, value * value)
    return float(np.sum(s2) - np.sum(s1 * s1 / np.maximum(n, 1)))


def rings_centre(x, y, value, pitch: float, reach: float = 0.75) -> tuple[float, float]:
    """Centre of the circular symmetry of ``value`` at the points ``(x, y)`` (Newton's rings'
    contact point, found without colour): the centre that minimises the variance of the
    intensity along circles (:func:`_circle_spread`), rings ``pitch`` wide (the pixel pitch).

    Searched on a grid that reaches ``reach`` of the photo's extent beyond its edges (a
    contact point outside the photo), then on grids three times finer around the best
    point down to a tenth of a pixel. Born and Wolf, *Principles of Optics*, sec. 7.5.3:
    the fringes of a spherical gap are circles about the contact point."""
    x, y, value = (np.asarray(a, np.float64) for a in (x, y, value))
    value = value - value.mean()
    span = max(float(np.ptp(x)), float(np.ptp(y)))
    mx, my = 0.5 * (x.max() + x.min()), 0.5 * (y.max() + y.min())
    half = (0.5 + reach) * span
    step = span / 24.0
    best = (mx, my)
    while step > 0.1 * pitch:
        offs = np.arange(-half, half + 0.5 * step, step)
        scores = [(_circle_spread(x, y, value, best[0] + u, best[1] + v, pitch), best[0] + u, best[1] + v)
                  for u in offs for v in offs]
        best = min(scores)[1:]
        half, step = 1.5 * step, step / 3.0
    return float(best[0]), float(best[1])


def rings_period(r2, value, r2_min_period: float) -> tuple[float, float]:
    """Period ``P`` (in ``r^2``) and phase of monochromatic Newton's rings about a known centre.

    Under one wavelength ``lambda`` the reflected intensity is ``a + b cos(4 pi n h / lambda + pi)``
    with ``h = h0 + r^2 / (2 R)`` (Born and Wolf, sec. 7.5.3; Hecht, *Optics*, sec. 9.4), so the
    dark rings' ``r_m^2 = (m lambda / (2 n) - h0) 2 R`` are linear in the order ``m``: the
    intensity is a sinusoid in ``r^2`` of period ``P = lambda R / n``. ``P`` is the period of
    the least-squares sinusoid ``a + c cos(2 pi r^2 / P) + s sin(2 pi r^2 / P)`` (a
    periodogram over ``P`` from ``r2_min_period`` to the largest ``r^2``, steps of a fiftieth
    of a fringe across the photo, then golden-section refined); returns ``(P, phi)`` with
    the intensity ``~ a + A cos(2 pi r^2 / P + phi)``, ``A > 0``."""
    r2, value = np.asarray(r2, np.float64), np.asarray(value, np.float64)
    span = float(r2.max() - r2.min())
    # the profile's means in bins a fortieth of the shortest period wide, weighted by count
    k = ((r2 - r2.min()) / (r2_min_period / 40.0)).astype(np.int64)
    cnt = np.bincount(k)
    keep = cnt > 0
    wt = np.sqrt(cnt[keep])
    mean = np.bincount(k, value)[keep] / cnt[keep]
    s2 = np.bincount(k, r2)[keep] / cnt[keep]

    def fit(p):
        w = 2.0 * np.pi * s2 / p
        A = np.column_stack([np.ones_like(s2), np.cos(w), np.sin(w)])
        coef, *_ = np.linalg.lstsq(A * wt[:, None], mean * wt, rcond=None)
        return float(np.sum(((A @ coef - mean) * wt) ** 2)), coef

    lo, hi = np.log(r2_min_period), np.log(max(span / 3.0, 2.0 * r2_min_period))  # three fringes at least
    # a fringe across the photo moves by span/P; a fiftieth of one in log P
    n = int(np.clip(50.0 * span / r2_min_period * (hi - lo), 200, 5000))
    grid = np.exp(np.linspace(lo, hi, n))
    costs = np.array([fit(p)[0] for p in grid])
    i = int(np.argmin(costs))
    a, b = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, n - 1)])
    g = 0.5 * (np.sqrt(5.0) - 1.0)
    for _ in range(40):  # golden section in log P between the neighbours
        c, d = b - g * (b - a), a + g * (b - a)
        if fit(np.exp(c))[0] < fit(np.exp(d))[0]:
            b = d
        else:
            a = c
    p = float(np.exp(0.5 * (a + b)))
    coef = fit(p)[1]
    return p, float(np.arctan2(-coef[2], coef[1]))


#: Width (pixels) of the Gaussian envelope divided out of the intensity before the rings'
#: centre and period are sought: it passes fringes narrower than ~2 pi 3 = 19 pixels and
#: removes the lamp's slow fall-off. Checked on the three real sodium photos of
#: experiments/real_photos.py (3 and 6 pixels give the same centres; 12 fails on one).
ENVELOPE_PX = 3.0


def _local_mean(bright, mask, width: float) -> np.ndarray:
    """The film pixels' local mean of ``bright``: a Gaussian of ``width`` pixels normalised
    over the film's pixels (a normalised convolution: pixels outside the film do not count)."""
    from scipy import ndimage

    img = np.zeros(mask.shape)
    img[mask] = bright
    return (ndimage.gaussian_filter(img, width) / np.maximum(ndimage.gaussian_filter(mask * 1.0, width), 1e-9))[mask]


def _fringes(bright, mask) -> np.ndarray:
    """The intensity over its local mean minus one (:func:`_local_mean`, a Gaussian of
    :data:`ENVELOPE_PX`): the fringes without the lamp's envelope."""
    return bright / np.maximum(_local_mean(bright, mask, ENVELOPE_PX), 1e-3 * float(np.max(bright))) - 1.0


#: Names of the lamp envelope's coefficients (:func:`lamp_envelope`), in the fit's order.
ENVELOPE_TERMS = ("envelope_x", "envelope_y", "envelope_xx", "envelope_xy", "envelope_yy")

#: Fewest fringes the rings' gap must span across the photo for ``envelope = "auto"`` to
#: fit the lamp's envelope with them. The envelope's quadratic has three coefficients
#: along each line across the photo; the fringes' maxima (where the gap's reflectance is
#: the same, ``R_max + b``) sample the lamp there, so three maxima along the line, three
#: fringes, fix it apart from the gap; with fewer a gap sloping across a fraction of a
#: fringe mimics the lamp's fall-off (the sodium photos of experiments/real_photos.py: a
#: flat gap of 0.8 fringes fitted their fall-off).
ENVELOPE_MIN_FRINGES = 3.0

#: Width (pixels) of the local mean whose log the envelope's start is fitted to: wider than
#: most fringes (1.5-20 pixels on the sodium photos of experiments/real_photos.py, their
#: development cases), so that the mean holds the lamp and the fringes' mean reflectance.
ENVELOPE_START_PX = 8.0


def envelope_coordinates(x, y) -> tuple[np.ndarray, np.ndarray]:
    """``(u, v)``: the film pixels' positions ``(x, y)`` about the photo's centre in units of
    half its larger side (``u, v`` within [-1, 1]), the coordinates of :func:`lamp_envelope`."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    half = 0.5 * max(float(np.ptp(x)), float(np.ptp(y)), 1e-12)
    return (x - 0.5 * (x.max() + x.min())) / half, (y - 0.5 * (y.max() + y.min())) / half


def envelope_basis(u, v, xp=np):
    """The columns ``(u, v, u^2, u v, v^2)`` of the envelope's log (:func:`lamp_envelope`,
    :data:`ENVELOPE_TERMS`) at :func:`envelope_coordinates` ``(u, v)``: shape ``(N, 5)``."""
    return xp.stack([u, v, u * u, u * v, v * v], axis=-1)


def lamp_envelope(u, v, coef):
    """The lamp's relative irradiance across the field, ``E = exp(c1 u + c2 v + c3 u^2 +
    c4 u v + c5 v^2)`` at :func:`envelope_coordinates` ``(u, v)`` (1 at the centre: the
    exposure holds its scale). A Gaussian spot of the lamp, or a flat field's vignetting,
    to second order in log (a smooth flat-field model; the two-beam intensity
    ``I = E (R1 + R2 + 2 sqrt(R1 R2) cos delta)`` of Born and Wolf, *Principles of Optics*,
    sec. 7.5, with ``E`` the lamp's irradiance where the pixel sees the film)."""
    return jnp.exp(envelope_basis(u, v, jnp) @ jnp.asarray(coef))


def _envelope_start(bright, mask, u, v) -> np.ndarray:
    """The envelope's coefficients (:func:`lamp_envelope`) nearest, by least squares, the log
    of the photo's local mean (:func:`_local_mean`, :data:`ENVELOPE_START_PX`), its
    constant left to the exposure: where the fringes are many, their mean reflectance is
    the same everywhere and the local mean follows the lamp."""
    mean = _local_mean(bright, mask, ENVELOPE_START_PX)
    a = np.column_stack([np.ones_like(u), envelope_basis(u, v)])
    coef, *_ = np.linalg.lstsq(a, np.log(np.maximum(mean, 1e-3 * max(float(np.max(mean)), 1e-12))), rcond=None)
    return coef[1:]


def _rings_start(fwd, x, yy, bright, mask, pitch: float, lo: float, hi: float):
    """``(R um, cx, cy, h0 nm, fringe nm)`` from the rings' circular symmetry and their period in ``r^2``
    (:func:`rings_centre`, :func:`rings_period`) of the fringes (:func:`_fringes`), at the
    lamp's mean wavelength through the camera (one wavelength for a line lamp), no colour
    used; the shortest period sought puts two pixels between rings at the median radius."""
    w = np.asarray(fwd.weights, np.float64).sum(-1)
    lam = float(np.sum(np.asarray(fwd.lam) * w) / np.sum(w))
    n = float(np.asarray(fwd.stack.indices(np.array([lam])).film)[0])
    value = _fringes(bright, mask)
    cx, cy = rings_centre(x, yy, value, pitch)
    r2 = (x - cx) ** 2 + (yy - cy) ** 2
    period, phi = rings_period(r2, value, 4.0 * pitch * float(np.median(np.sqrt(r2))))
    radius = period * n / (lam / 1000.0)  # um: P = lambda R / n
    fringe = lam / (2.0 * n)  # phase 4 pi n h0 / lambda + pi = phi (mod 2 pi)
    h0 = ((phi - np.pi) / (2.0 * np.pi) % 1.0) * fringe
    h0 = float(np.clip(h0, lo, hi))
    return radius, cx, cy, h0, fringe


#: Share of the map's pixels (in the lower half of the searched range) within a tenth of a
#: fringe of the colour start's line in ``r^2`` above which that start is unambiguous and
#: the colour-free one is not sought. A map of the right orders lies on the line within its
#: noise (nanometres; a tenth of a fringe is 27 nm in air) save its order hops; a map under
#: one wavelength folds every fringe onto the first and leaves about half its pixels near
#: any line. Development cases: film_newton_bk7_na010 (0.96 of its pixels) and the 850 mm
#: sodium photo of experiments/real_photos.py (0.49).
UNAMBIGUOUS_SHARE = 0.75


def colour_start(x, yy, dmap, bright, lo: float, hi: float, fringe_nm: float):
    """``((R um, cx, cy, h0 nm) or None, unambiguous)``: the start from the per-pixel map
    ``dmap``: the centre of its thinnest dark pixels, and ``R``, ``h0`` from a straight
    line of the map against ``r^2`` (``h ~ h0 + r^2 / (2 R)``, Born and Wolf sec. 7.5.3)
    where the map is below half the searched range, dropping pixels 3 MADs off it (order
    hops of the map); unambiguous when :data:`UNAMBIGUOUS_SHARE` of those pixels lie
    within a tenth of a fringe (``fringe_nm``) of the line."""
    x, yy, dmap, bright = (np.asarray(a, np.float64) for a in (x, yy, dmap, bright))
    thin = (dmap <= np.percentile(dmap, 2)) & (bright <= 0.35 * np.median(bright))
    if thin.sum() < 3:
        return None, False
    cx, cy = float(x[thin].mean()), float(yy[thin].mean())
    r2 = (x - cx) ** 2 + (yy - cy) ** 2
    below = dmap < lo + 0.5 * (hi - lo)
    use = below.copy()
    for _ in range(4):
        A = np.column_stack([np.ones(use.sum()), r2[use]])
        (h0, slope), *_ = np.linalg.lstsq(A, dmap[use], rcond=None)
        dev = np.abs(dmap - (h0 + slope * r2))
        use = use & (dev <= 3.0 * 1.4826 * np.median(dev[use]) + 1.0)
    if slope <= 0:
        return None, False
    share = float(np.mean(dev[below] <= 0.1 * fringe_nm))
    return (1000.0 / (2.0 * slope), cx, cy, float(h0)), share >= UNAMBIGUOUS_SHARE  # um: h[nm] = 1000 r^2 / (2 R)


#: Ratio of the fitted gap's span across the photo to that of the rings' period without
#: colour (either way) past which the fit is taken to have lost the rings: a fit that found
#: them moves R, and the span, by the start's few per cent (2 % on the three sodium photos
#: of experiments/real_photos.py against their ring diameters); one that ran to a flat gap
#: keeps a fraction of a fringe of tens.
LOST_RINGS_RATIO = 2.0


def lost_rings_warning(start_span_nm: float, fitted_span_nm: float, fringe_nm: float, start_radius_um: float,
                       fitted_radius_um: float) -> str | None:
    """A warning where the fitted gap spans :data:`LOST_RINGS_RATIO` times fewer (or more)
    fringes across the photo than the rings' period without colour says (the gap
    ``h = h0 + r^2 / (2 R)``, Born and Wolf sec. 7.5.3, across the photo's pixels, in
    fringes of ``fringe_nm``); None where they agree."""
    ratio = fitted_span_nm / max(start_span_nm, 1e-9)
    if 1.0 / LOST_RINGS_RATIO <= ratio <= LOST_RINGS_RATIO:
        return None
    return (f"the fitted lens (R = {fitted_radius_um / 1000.0:.4g} mm) spans {fitted_span_nm / fringe_nm:.1f} fringes "
            f"across the photo where its rings' period without colour spans {start_span_nm / fringe_nm:.1f} "
            f"(R = {start_radius_um / 1000.0:.4g} mm): the fit lost the rings (fringes fainter than the model's, "
            "from stray light or the lamp's fall-off, are fitted better by a nearly uniform gap); R is not the lens's")


def _linear_exposure(unit, white, y, fit_stray: bool) -> tuple[float, float]:
    """``(g, b)`` minimising ``|g (unit + b white) - y|^2`` (the model's exposure and stray
    reflectance are linear in ``(g, g b)``: least squares), ``b`` held at 0 where it is not
    fitted or would be negative (a reflectance), ``g > 0``."""
    u, w_, yv = (np.asarray(a, np.float64).ravel() for a in (unit, white, y))
    if fit_stray:
        (g, c), *_ = np.linalg.lstsq(np.column_stack([u, w_]), yv, rcond=None)
        if g > 0 and c >= 0:
            return float(g), float(c / g)
    return max(float(u @ yv) / max(float(u @ u), 1e-20), 1e-9), 0.0


def _best_start(starts, film_only, fringe_nm: float, xj, yj, y, white, env0, e0, envelope: str, fit_stray: bool):
    """``(theta, envelope on)``: of the starts ``(R um, cx, cy, h0)``, the one whose colours
    are nearest the photo, with the exposure (and the stray reflectance where it is fitted)
    by least squares at each (:func:`_linear_exposure`) under the envelope's start ``env0``
    (``e0``: its values at the film's pixels) where the envelope is fitted there (:data:`ENVELOPE_MIN_FRINGES` for ``"auto"``).
    ``film_only``: the film's colours at unit exposure, ``b`` fixed; ``white``: the colour of
    ``b = 1``."""
    best = None
    for radius, cx, cy, h0 in starts:
        t = jnp.asarray([np.log(radius), cx, cy, h0, 0.0])
        span = float(np.ptp(np.asarray(newton_gap(jnp.sqrt((xj - cx) ** 2 + (yj - cy) ** 2), radius, h0))))
        env = envelope == "fit" or (envelope == "auto" and span >= ENVELOPE_MIN_FRINGES * fringe_nm)
        e = e0 if env else 1.0
        unit = np.asarray(film_only(t), np.float64) * e
        g, b = _linear_exposure(unit, white * e, y, fit_stray)
        cost = float(np.sum((g * (unit + b * white * e) - y) ** 2))
        if best is None or cost < best[0]:
            best = (cost, [np.log(radius), cx, cy, h0, np.log(g)] + ([b] if fit_stray else [])
                    + (list(env0) if env else []), env)
    return jnp.asarray(best[1]), best[2]


def _reported(t, cov, u, v, fit_stray: bool, b_fixed: float, b_se, env_on: bool) -> tuple[dict, dict]:
    """The Newton fit's reported values and standard errors from its parameters ``t``
    (``log R``, centre, contact offset, ``log g``, then ``b`` where fitted and the
    envelope's coefficients where fitted) and their covariance: ``R`` in mm, the exposure,
    the stray reflectance (``b_se``: the unbounded fit's error of a ``b`` held at its bound),
    the envelope's coefficients and its ratio ``max E / min E`` over the film (log E is
    linear in the coefficients: its error from their covariance)."""
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    radius_um = float(np.exp(t[0]))
    params = {"radius_mm": radius_um / 1000.0, "center_x_um": float(t[1]), "center_y_um": float(t[2]),
              "contact_offset_nm": float(t[3]), "exposure": float(np.exp(t[4]))}
    stderr = {"radius_mm": radius_um / 1000.0 * float(se[0]), "center_x_um": float(se[1]),
              "center_y_um": float(se[2]), "contact_offset_nm": float(se[3]), "exposure": float(np.exp(t[4]) * se[4])}
    params["stray_reflectance"] = float(t[5]) if fit_stray else b_fixed
    stderr["stray_reflectance"] = float(se[5]) if fit_stray else (b_se if b_se is not None else 0.0)
    ie = 6 if fit_stray else 5
    for k, name in enumerate(ENVELOPE_TERMS):
        params[name] = float(t[ie + k]) if env_on else 0.0
        stderr[name] = float(se[ie + k]) if env_on else 0.0
    params["envelope_ratio"], stderr["envelope_ratio"] = 1.0, 0.0
    if env_on:
        basis = envelope_basis(u, v)
        log_e = basis @ t[ie:ie + len(ENVELOPE_TERMS)]
        d = basis[int(np.argmax(log_e))] - basis[int(np.argmin(log_e))]
        c = cov[ie:ie + len(ENVELOPE_TERMS), ie:ie + len(ENVELOPE_TERMS)]
        params["envelope_ratio"] = float(np.exp(np.ptp(log_e)))
        stderr["envelope_ratio"] = params["envelope_ratio"] * float(np.sqrt(max(float(d @ c @ d), 0.0)))
    return params, stderr


def _lens_gap(theta, cov, x, y) -> tuple[np.ndarray, np.ndarray]:
    """The fitted lens's gap :func:`newton_gap` at the film's pixels ``(x, y)`` (um) and its
    standard error, ``sqrt(j C j^T)`` with ``j`` the gap's gradient in ``(log R, cx, cy, h0)``
    (``theta``'s first four) and ``C`` their covariance (GUM, JCGM 100:2008, eq. 13)."""
    t = np.asarray(theta, np.float64)
    h = np.asarray(newton_gap(jnp.asarray(np.sqrt((x - t[1]) ** 2 + (y - t[2]) ** 2)), float(np.exp(t[0])), t[3]))
    xj, yj = jnp.asarray(x), jnp.asarray(y)
    hj = jax.jacfwd(lambda q: newton_gap(jnp.sqrt((xj - q[1]) ** 2 + (yj - q[2]) ** 2), jnp.exp(q[0]), q[3]))(theta)
    hj = np.asarray(hj, np.float64)
    return h, np.sqrt(np.clip(np.einsum("pi,ij,pj->p", hj, cov, hj), 0.0, None))


def _covariance(J, r, cost: float, copies: int, pixels: np.ndarray, shape: tuple) -> np.ndarray:
    """The parameters' covariance at the optimum (``J``, ``r`` the whitened Jacobian and
    residual of ``pixels``, flat indices into an image of ``shape``; ``copies`` 3 for a grey
    photo, whose channels repeat each pixel): the misfit's scatter (the Birge ratio, over
    the pixels' own degrees of freedom) or, where a model error runs smoothly across the
    photo (a gap that is not one sphere, rings that are not circles), the cluster sandwich
    over blocks of the film, whichever is wider (:func:`._uncertainty.widened_over_film`)."""
    dof = max(len(r) // copies - J.shape[1], 1)
    a_inv = np.linalg.pinv(J.T @ J)
    return widened_over_film(a_inv * (cost / dof), a_inv, J, r, pixels, shape)[0]


def fit_newton(fwd, y, lum, sin2, view, mask, dmap, gain, sigma, lo, hi, high=np.inf, iters: int = 40,
               stray=STRAY_DEFAULT, envelope=ENVELOPE_DEFAULT) -> ModelFit:
    """Levenberg-Marquardt fit of ``(R, cx, cy, h0, g)`` (see the module), started from ``dmap``,
    of the stray reflectance ``b`` where ``stray == "fit"``, and of the lamp's envelope
    where ``envelope`` says so.

    The pixel's colour is ``g E(x, y) L rgb(R(h) + b)`` (:meth:`~bubblefit.inverse.planar.PlanarForward.rgb`):
    ``b`` is the grey reflectance of the light that reaches the camera without interfering
    (the lens's top and the plate's bottom reflect about 4 % each by Fresnel, nearly flat in
    wavelength: grey; scatter), added in intensity (Born and Wolf, sec. 7.5.1). The rings'
    maxima and minima fix ``g`` and ``b`` apart. Fitted, ``b`` is bounded at 0: a fit that
    takes it below is refitted with ``b = 0``, which is reported with the unbounded fit's
    standard error. A number fixes ``b``.

    ``E`` (:func:`lamp_envelope`, five coefficients :data:`ENVELOPE_TERMS`) is the lamp's
    irradiance across the field, shared by the interfering and the stray light (one lamp):
    ``"fit"`` fits it, ``"none"`` holds it at 1, ``"auto"`` fits it where the start's gap
    spans :data:`ENVELOPE_MIN_FRINGES` fringes across the photo (then the fringes' maxima
    and minima fix it apart from the gap). Its start is :func:`_envelope_start`.
    ``envelope_ratio`` in the parameters is ``E``'s largest over its least value on the film.

    ``[lo, hi]``, the searched range, bounds the per-pixel map ``dmap`` (the colour start)
    and the contact offset's neighbouring orders; the lens's gap is held at ``lo`` only
    (a pressed lens's flat): past ``hi`` it is the lens's, through the forward
    :meth:`~bubblefit.inverse.planar.PlanarForward.reaching` the start lens's largest gap."""
    fit_stray = stray == "fit"
    b_fixed = 0.0 if fit_stray else float(stray)
    x = view.x_um[mask]
    yy = view.y_um[mask]
    bright = y.sum(-1) / np.maximum(lum, 1e-9)
    u, v = envelope_coordinates(x, yy)
    xj, yj, lj, sj, obs, uj, vj = (jnp.asarray(a) for a in (x, yy, lum, sin2, y, u, v))
    pitch = float(np.median(np.abs(np.diff(np.unique(np.round(x, 6))))))
    every = np.ones(len(x), bool)

    def make_model(free: bool, env: bool, keep=every):
        ie = 6 if free else 5  # the envelope's coefficients after the exposure (and b)
        xk, yk, lk, sk, uk, vk = (a[keep] for a in (xj, yj, lj, sj, uj, vj))

        def model(t):
            dx, dy = xk - t[1], yk - t[2]
            h = jnp.maximum(newton_gap(jnp.sqrt(dx * dx + dy * dy), jnp.exp(t[0]), t[3]), lo)
            gx, gy = newton_gap_gradient(dx, dy, jnp.exp(t[0]))
            b = t[5] if free else b_fixed
            # the film's reflectance averaged over each pixel's box (the camera's aperture)
            out = jnp.exp(t[4]) * lk[:, None] * pixel_mean(fwd, h, sk, b, gx, gy, pitch, lo, np.inf)
            return out * lamp_envelope(uk, vk, t[ie:ie + len(ENVELOPE_TERMS)])[:, None] if env else out

        return model

    # two starts, the colour map's and the rings' symmetry's (no colour: the one that
    # works under a line lamp); the fit starts from the one whose colours are closer. The
    # second is sought only where the first is ambiguous (:func:`colour_start`).
    start, unambiguous = colour_start(x, yy, dmap, bright, lo, hi, fwd.fringe_nm)
    starts = [] if start is None else [start]
    rings = None
    if not unambiguous:
        rings = _rings_start(fwd, x, yy, bright, mask, pitch, lo, hi)
        starts.append(rings[:4])
    zero = jnp.zeros(sj.shape)
    white = np.asarray(lj[:, None] * (fwd.rgb(zero, sj, 1.0) - fwd.rgb(zero, sj)), np.float64)  # rgb of b = 1
    env0 = _envelope_start(bright, mask, u, v) if envelope != "none" else np.zeros(len(ENVELOPE_TERMS))
    e0 = np.asarray(lamp_envelope(u, v, env0), np.float64)[:, None]
    theta, env_on = _best_start(starts, make_model(False, False), fwd.fringe_nm, xj, yj, y, white, env0, e0,
                                envelope, fit_stray)
    # the lens's gap is not held within the searched range [lo, hi] (that bounds the
    # per-pixel map, the colour start): it is the lens's wherever the photo reaches, and
    # the forward resolves it up to the start's largest gap on the photo
    fwd = fwd.reaching(float(jnp.max(newton_gap(jnp.sqrt((xj - theta[1]) ** 2 + (yj - theta[2]) ** 2),
                                                jnp.exp(theta[0]), theta[3]))))
    # rings finer than two pixels alias: left out of the fit (the start's lens says where)
    gx0, gy0 = newton_gap_gradient(xj - theta[1], yj - theta[2], jnp.exp(theta[0]))
    aliased = aliased_pixels(gx0, gy0, pitch, fwd.fringe_nm)
    notes = []
    if aliased.any():
        notes.append(f"the rings are aliased on {int(aliased.sum())} of the film's {len(aliased)} pixels (fringes "
                     f"under {MIN_FRINGE_PX:g} pixels apart, from the start's lens): those pixels are left out of the fit")
    keep = ~aliased
    if keep.sum() < 2 * (len(theta) + 1):
        keep = every
    obs_k, sin2_k = obs[keep], np.asarray(sin2)[keep]
    model = make_model(fit_stray, env_on, keep)
    xk, yk = xj[keep], yj[keep]

    def gap(t):
        return jnp.maximum(newton_gap(jnp.sqrt((xk - t[1]) ** 2 + (yk - t[2]) ** 2), jnp.exp(t[0]), t[3]), lo)

    theta, r, cost, J = fit_colours(model, obs_k, sigma, high, theta, iters)
    # a grey photo (three equal channels) measures each pixel once, not three times: its
    # residuals come in identical threes, and sigma^2 (J^T J)^-1 counted over all of them
    # is 1/3 of the covariance (sigma^2 estimated over the pixels, the normal matrix over
    # one channel's rows)
    copies = 3 if np.array_equal(y[:, 0], y[:, 1]) and np.array_equal(y[:, 1], y[:, 2]) else 1
    b_se = None
    if fit_stray and float(theta[5]) < 0.0:  # a reflectance: at its bound, refitted without it
        b_se = float(np.sqrt(max(float(_covariance(J, r, cost, copies, np.flatnonzero(mask)[keep], mask.shape)[5, 5]),
                                 0.0)))
        fit_stray, b_fixed = False, 0.0
        model = make_model(False, env_on, keep)
        theta, r, cost, J = fit_colours(model, obs_k, sigma, high, jnp.concatenate([theta[:5], theta[6:]]), iters)
    # the rings' order is the contact offset's: every ring moves with it (bubblefit.inverse.order_check)
    order = fit_order(fwd, model, gap, obs_k, sigma, high, (theta, r, cost, J), {"contact_offset_nm": 3}, sin2_k, lo,
                      hi, iters)
    cov = _covariance(J, r, cost, copies, np.flatnonzero(mask)[keep], mask.shape)
    t = np.asarray(theta, np.float64)
    radius_um = float(np.exp(t[0]))
    h, h_se = _lens_gap(theta, cov, x, yy)
    params, stderr = _reported(t, cov, u, v, fit_stray, b_fixed, b_se, env_on)
    warnings = []
    if rings is not None:  # the gap across the photo, fitted and from the rings' period without colour
        r2s = (x - rings[1]) ** 2 + (yy - rings[2]) ** 2
        lost = lost_rings_warning(1000.0 * float(np.ptp(r2s)) / (2.0 * rings[0]), float(np.ptp(h)), rings[4],
                                  rings[0], radius_um)
        warnings += [lost] if lost else []
    return ModelFit(params=params, stderr=stderr, thickness=h, thickness_stderr=h_se,
                     model=np.asarray(make_model(fit_stray, env_on)(theta), np.float64), gain=float(np.exp(t[4])),
                     order=order, warnings=warnings, notes=notes, fitted=keep)
