"""Transmission fraction t from photographs with and without the bubble (paper, sec. 3.3).

A bubble sits on a matte black dish inside a matte black box in front of a checkered
background. A fixed camera takes one photograph without the bubble (``before``) and one
with it (``after``). Background light crosses four film/air interfaces, so inside the
bubble ``after / before = t^4`` (paper, sec. 3.3), with t the per-interface transmission
fraction that the paper's eq. (14) ties to the reflectances, ``r_d + r_s = 1 - t``.

:func:`calibrate` is a short pipeline of named steps, each in its own module:

1. :mod:`.registration`: the camera shift between the shots, by phase correlation
   (Kuglin & Hines 1975) refined by ECC (Evangelidis & Psarakis 2008), with the bubble
   masked out on the second pass. A low correlation means two different scenes.
2. :func:`.ratio.usable_mask`: pixels whose ratio is reliable: lit (not the black
   squares, the box or the dish), unsaturated in both shots, away from the checker edges.
3. :func:`.circle.detect_bubble`: the bubble, as the largest darkened disc of the
   smoothed ratio image, its rim fitted by the algebraic circle fit (Kasa 1976).
4. :func:`.profile.fit_disc_profile`: a sub-pixel refinement of the circle by least
   squares on the ratio around the rim, with a radial profile that bridges the paper's
   constant ``t^4`` (``beta = 0``) and the Fresnel film of the ``physical`` variant
   (``beta = 1``).
5. :func:`.ratio.robust_ratio` and :func:`.ratio.block_bootstrap_ratio`: t from the pixels
   well inside the bubble (``rho <= inner_fraction``), normalised by the same ratio
   outside the bubble (exposure drift), with a 95% interval from a block bootstrap.
6. The refractive index (:func:`.profile.n_from_t4`): when the rim fall-off confirms the
   Fresnel film, t is the normal-incidence value (interior pixels divided by the model's
   angular factor ``S(rho)``) and ``n_film`` is reported with its interval.

All images are linear RGB arrays (H, W, 3). Circles given to and returned by
:func:`calibrate` (and the ``--circle`` option, and the JSON) use the convention of
:class:`bubblefit.model.geometry.OrthographicCamera`: x right, y down, the image's top-left
corner at (0, 0), so the centre of pixel (row i, column j) is (j + 1/2, i + 1/2). The
step modules work in array coordinates, where that centre is (j, i). See
``docs/design.md`` (calibration).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..errors import InputError
from ..io.images import Image
from .circle import detect_bubble
from .pair import check_exposures, gray, load_pair
from .profile import DEFAULT_N, fit_disc_profile, fresnel_shape, n_from_t4
from .ratio import ChannelRatio, channel_ratios, model_error, ratio_interval, usable_mask, with_gray
from .registration import register_translation, shift_image
from .result import CalibrationResult, save_json, write_debug_image

__all__ = ["CalibrationResult", "calibrate", "load_pair", "save_json", "write_debug_image"]

#: Smallest side of a calibration photo, pixels (registration and the bubble need room).
MIN_SIDE = 16

#: What the ratio's fall-off toward the rim supports (:func:`_radial_model`).
RadialModel = Literal["fresnel", "constant", "other", "undetermined"]


# --------------------------------------------------------------------------------------
# The steps
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Registered:
    """``before`` registered onto ``after`` (:func:`_register`), and its usable pixels."""

    shift: tuple[float, float]
    cc: float
    gray_before: np.ndarray  # (H, W), shifted
    saturated: np.ndarray  # (H, W) bool, in either shot
    usable: np.ndarray  # (H, W) bool
    parts: dict[str, np.ndarray]


def _given_circle(circle, w: int, h: int) -> tuple[float, float, float]:
    """A circle given in image coordinates (pixel centres at +1/2), checked, in array coordinates."""
    cx, cy, r = (float(v) for v in circle)
    if not (np.isfinite([cx, cy, r]).all() and r > 0):
        raise InputError(f"circle: need a finite centre and a positive radius, got {circle}")
    if not (-r < cx < w + r and -r < cy < h + r):
        raise InputError(f"circle: the centre ({cx:g}, {cy:g}) is outside the {w}x{h} image")
    slack = 0.02 * r  # a rim drawn by hand a pixel or two past the frame's edge
    if cx - r < -slack or cy - r < -slack or cx + r > w + slack or cy + r > h + slack:
        raise InputError(f"circle: radius {r:g} around ({cx:g}, {cy:g}) reaches beyond the {w}x{h} image; the "
                         "whole bubble and background around it must be in the frame")
    return cx - 0.5, cy - 0.5, r


def _outside(shape: tuple[int, int], circle: tuple[float, float, float]) -> np.ndarray:
    """Pixels clear of the bubble: farther than ``1.2 r + 3`` from its centre."""
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    cx, cy, r = circle
    return np.hypot(xx - cx, yy - cy) > 1.2 * r + 3


def _register(img_b: Image, img_a: Image, shift: tuple[float, float], cc: float) -> _Registered:
    """Shift ``before`` onto ``after`` and find the pixels whose ratio is usable."""
    h, w = img_b.shape
    sat_b = img_b.saturated if img_b.saturated is not None else np.zeros((h, w), bool)
    sat_a = img_a.saturated if img_a.saturated is not None else np.zeros((h, w), bool)
    gb_r = shift_image(gray(img_b.pixels), shift)
    sat = shift_image(sat_b, shift, order="nearest") | sat_a
    valid_src = shift_image(np.ones((h, w), bool), shift, order="nearest")
    usable, parts = usable_mask(gb_r, gray(img_a.pixels), sat)
    return _Registered(shift, cc, gb_r, sat, usable & valid_src, parts)


def _first_registration(
    img_b: Image, img_a: Image, mask: np.ndarray | None, max_shift: float, min_cc: float, names: tuple[str, str]
) -> _Registered:
    """Registration over the whole frame (or outside a given circle); refuses moved cameras."""
    shift, cc = register_translation(gray(img_a.pixels), gray(img_b.pixels), mask=mask)
    nb, na = names
    if cc < min_cc:
        raise InputError(
            f"{nb} and {na} do not show the same scene: correlation {cc:.2f} after registration "
            f"(need at least {min_cc:.2f}); the camera and background must not change between shots"
        )
    if max(abs(shift[0]), abs(shift[1])) > max_shift:
        raise InputError(
            f"the camera moved by ({shift[0]:.1f}, {shift[1]:.1f}) pixels between {nb} and {na}; "
            f"calibration needs a fixed camera (at most {max_shift:.0f} pixels)"
        )
    return _register(img_b, img_a, shift, cc)


def _second_registration(img_b: Image, img_a: Image, reg: _Registered, circle, warnings: list[str]) -> _Registered:
    """Registration refined on the background only, once the bubble is known."""
    outside = _outside(img_b.shape, circle)
    if outside.mean() > 0.05:
        shift2, cc2 = register_translation(gray(img_a.pixels), gray(img_b.pixels), mask=outside, init=reg.shift)
        if cc2 > 0 and math.hypot(shift2[0] - reg.shift[0], shift2[1] - reg.shift[1]) < 3:
            reg = _register(img_b, img_a, shift2, cc2)
    if reg.cc < 0.9:
        warnings.append(f"low correlation between the shots outside the bubble ({reg.cc:.3f}): did the scene change?")
    return reg


def _swapped_error(names: tuple[str, str]) -> InputError:
    return InputError(
        f"the bubble is brighter in {names[1]} than in {names[0]}: more light than no film at all, so the files "
        "look swapped (BEFORE is the shot without the bubble, AFTER the one with it)"
    )


def _detect(img_a: Image, reg: _Registered, names: tuple[str, str]) -> tuple[float, float, float]:
    """The bubble of the pair (:func:`detect_bubble`: the largest disc that darkens the
    background). A larger disc that brightens it instead means swapped files."""
    ga = gray(img_a.pixels)
    try:
        circle = detect_bubble(reg.gray_before, ga, reg.usable)
    except InputError as exc:
        circle, error = None, exc
    try:
        brighter = detect_bubble(ga, reg.gray_before, reg.usable)
    except InputError:
        brighter = None
    def contrast(c):  # median ratio well inside the circle over the median outside it
        d = np.hypot(*(np.mgrid[0 : ga.shape[0], 0 : ga.shape[1]][::-1] - np.array(c[:2])[:, None, None]))
        q = np.where(reg.usable, ga / np.where(reg.usable, reg.gray_before, 1.0), np.nan)
        inside, outside = q[d < 0.7 * c[2]], q[d > 1.2 * c[2] + 3]
        if not (np.isfinite(inside).any() and np.isfinite(outside).any()):
            return 1.0
        return float(np.nanmedian(inside) / np.nanmedian(outside))

    darker = circle is not None and contrast(circle) < 1.0
    if brighter is not None and (not darker or brighter[2] > 1.5 * circle[2]) and contrast(brighter) > 1.0:
        raise _swapped_error(names)
    if circle is None:
        raise error
    return circle


def _refine(ga: np.ndarray, reg: _Registered, circle, given: bool, seed: int, warnings: list[str]):
    """Sub-pixel circle and radial fall-off from :func:`fit_disc_profile`; returns (circle, profile)."""
    cx, cy, r = circle
    prof = fit_disc_profile(reg.gray_before, ga, reg.usable, circle, fix_geometry=given, seed=seed)
    if not given:
        if prof["success"] and math.hypot(prof["cx"] - cx, prof["cy"] - cy) < 0.5 * r and 0.5 * r < prof["r"] < 1.5 * r:
            cx, cy, r = prof["cx"], prof["cy"], prof["r"]
        else:
            warnings.append("the circle refinement did not converge near the detected circle; using the detection")
    return (cx, cy, r), prof


def _radial_model(prof: dict[str, Any]) -> RadialModel:
    """Which model the ratio's fall-off toward the rim supports: beta near 1 is the Fresnel
    film, near 0 the paper's constant t (within 3 standard errors or 0.15)."""
    beta, beta_se = prof["beta"], prof["beta_stderr"]
    determined = prof["n_rim_pixels"] >= 100 and beta_se <= 0.2
    if not determined:
        return "undetermined"
    if abs(beta - 1.0) <= max(3 * beta_se, 0.15):
        return "fresnel"
    if abs(beta) <= max(3 * beta_se, 0.15):
        return "constant"
    return "other"


def _exposure(
    pa: np.ndarray, ga: np.ndarray, pb_r: np.ndarray, reg: _Registered, outer: np.ndarray, bid: np.ndarray,
    enabled: bool, warnings: list[str],
) -> ChannelRatio | None:
    """The after/before ratio of the background outside the bubble (exposure drift), or None."""
    if enabled and outer.sum() >= 200:
        out = channel_ratios(with_gray(pa, ga, outer), with_gray(pb_r, reg.gray_before, outer), bid[outer])
        exposure = float(out.k[3])
        if abs(exposure - 1.0) > 0.02:
            warnings.append(
                f"the exposure changed by {100 * (exposure - 1):+.1f}% between the shots "
                "(measured outside the bubble); t is corrected for it"
            )
        return out
    if enabled:
        warnings.append("too little background outside the bubble to check the exposure; assumed unchanged")
    return None


def _refit_index(inside: ChannelRatio, t4_all, k_out, a_in, b_in, rho, bid) -> tuple[ChannelRatio, np.ndarray, float]:
    """With the Fresnel film confirmed: the index from the centre ratio (:func:`n_from_t4`)
    and the ratios again with the angular factor of that index."""
    n_est = n_from_t4(float(t4_all[3]))
    if np.isfinite(n_est) and 1.2 < n_est < 2.0 and abs(n_est - DEFAULT_N) > 1e-3:
        inside = channel_ratios(a_in / fresnel_shape(rho, n_est)[:, None], b_in, bid)
        return inside, inside.k / k_out, n_est
    return inside, t4_all, DEFAULT_N


def _n_film(model: RadialModel, beta: float, beta_se: float, t4: float, lo4: float, hi4: float, warnings: list[str]):
    """The film's index from the centre ratio when the Fresnel model is supported.

    Returns ``(n, stderr, [lo, hi])`` or ``(None, None, None)``; the interval of ``t^4``
    maps through the monotone :func:`n_from_t4`.
    """
    if model == "fresnel":
        n_est, n_a, n_b = n_from_t4(t4), n_from_t4(hi4), n_from_t4(lo4)
        if all(np.isfinite([n_est, n_a, n_b])):
            if not (1.30 <= n_est <= 1.50):
                warnings.append(
                    f"n_film = {n_est:.3f} is implausible for a soap film: the film may absorb or scatter, "
                    "or the lighting changed"
                )
            return n_est, (n_b - n_a) / (2 * 1.959964), [n_a, n_b]
        warnings.append("the ratio at the centre is outside the range of a lossless film; n_film not reported")
    elif model == "constant":
        warnings.append(
            "the ratio does not fall toward the rim as the Fresnel film model predicts (paper's constant t); "
            "n_film not reported"
        )
    elif model == "other":
        warnings.append(
            f"the radial fall-off of the ratio (beta = {beta:.2f} +/- {beta_se:.2f}) matches neither the Fresnel "
            "film (1) nor a constant t (0); n_film not reported"
        )
    else:
        warnings.append(
            "too few pixels near the rim to fit the Fresnel film model (bubble too small in the image or rim "
            "too dark); n_film not reported, t corrected with n = 1.4"
        )
    return None, None, None


def _inner_pixels(reg: _Registered, d: np.ndarray, r: float, inner_fraction: float, min_pixels: int) -> np.ndarray:
    """Usable pixels within ``inner_fraction * r`` of the centre and 3 pixels inside the rim."""
    inner = (d / r <= inner_fraction) & (d <= r - 3)
    used = reg.usable & inner
    if int(used.sum()) < min_pixels:
        n_sat = int((inner & reg.saturated).sum())
        n_dark = int((inner & ~reg.parts["lit"]).sum())
        raise InputError(
            f"too few usable pixels inside the bubble ({int(used.sum())} of {int(inner.sum())}, need {min_pixels}): "
            f"{n_sat} saturated, {n_dark} too dark; adjust the exposure or use a larger bubble"
        )
    return used


def _registered_bubble(img_b: Image, img_a: Image, circle, max_shift: float | None, min_cc: float,
                       names: tuple[str, str], warnings: list[str]) -> tuple[_Registered, tuple, bool]:
    """``(registration, circle, given)``: the pair registered over the whole frame (outside a
    given circle), the bubble (given or detected) and the pair registered again outside it."""
    h, w = img_b.shape
    given = circle is not None
    if given:
        circle = _given_circle(circle, w, h)
    if max_shift is None:
        max_shift = max(8.0, 0.1 * min(h, w))
    reg = _first_registration(img_b, img_a, _outside((h, w), circle) if given else None, max_shift, min_cc, names)
    if not given:
        circle = _detect(img_a, reg, names)
    if circle[2] < 4:
        raise InputError(f"the bubble is too small in the image (radius {circle[2]:.1f} pixels); move the camera closer")
    reg = _second_registration(img_b, img_a, reg, circle, warnings)
    return reg, circle, given


@dataclass(frozen=True)
class _T4:
    """The measured ``t^4`` per channel (R, G, B, grey) with its interval (sec. 3.3)."""

    t4: np.ndarray
    lo4: np.ndarray
    hi4: np.ndarray
    model_sd: np.ndarray  # the model error carried by the interval (:func:`~.ratio.model_error`)
    k_out: np.ndarray  # the exposure ratio outside the bubble (ones when not corrected)
    exposure_corrected: bool
    n_shape: float  # the index of the angular correction
    fresnel_corrected: bool
    blocks_inside: int  # pixel blocks inside the bubble (the bootstrap's units)


def _t4_ratio(img_b: Image, pa, ga, reg: _Registered, used, outer, rho, radial_model: RadialModel,
              exposure_correction: bool, n_boot: int, seed: int, warnings: list[str]) -> _T4:
    """``t^4``: the robust after/before ratio over the ``used`` pixels, corrected for the
    Fresnel fall-off toward the rim where the profile does not rule it out, over the ratio
    outside the bubble (``outer``), with its block-bootstrap interval and model error; the
    index of the angular correction refitted when the Fresnel film is supported."""
    h, w = ga.shape
    yy, xx = np.mgrid[0:h, 0:w]
    outer = reg.usable & outer
    pb_r = np.stack([shift_image(img_b.pixels[..., c], reg.shift) for c in range(3)], axis=-1)
    block = int(np.clip(min(h, w) // 64, 4, 16))
    bid = (yy // block) * (w // block + 1) + xx // block
    a_in, b_in = with_gray(pa, ga, used), with_gray(pb_r, reg.gray_before, used)
    fresnel_corrected = radial_model in ("fresnel", "undetermined")
    n_shape = DEFAULT_N
    # physics prior: a real film transmits less at oblique incidence (Fresnel)
    corr = fresnel_shape(rho[used], n_shape) if fresnel_corrected else np.ones(int(used.sum()))
    inside = channel_ratios(a_in / corr[:, None], b_in, bid[used])
    outside = _exposure(pa, ga, pb_r, reg, outer, bid, exposure_correction, warnings)
    k_out = outside.k if outside is not None else np.ones(4)
    t4_all = inside.k / k_out
    if np.any(t4_all <= 0):
        raise InputError("no light is transmitted through the bubble region: check the circle and the shots")
    # the index, and the angular correction with it, when the Fresnel film is supported
    if radial_model == "fresnel":
        inside, t4_all, n_shape = _refit_index(inside, t4_all, k_out, a_in, b_in, rho[used], bid[used])
    corr = fresnel_shape(rho[used], n_shape) if fresnel_corrected else np.ones(int(used.sum()))
    model_sd = model_error(a_in, b_in, corr, rho[used], bid[used], k_out, t4_all, radial_model, n_shape)
    lo4, hi4 = ratio_interval(inside, outside, t4_all, n_boot, np.random.default_rng(seed), model_sd)
    return _T4(t4_all, lo4, hi4, model_sd, k_out, outside is not None, n_shape, fresnel_corrected,
               int(inside.a_blocks.shape[0]))


def _t_from_t4(q: _T4, names: tuple[str, str], warnings: list[str]):
    """``(t, lower, upper)`` per channel: ``t^4``'s fourth root and its interval's; a ``t``
    above 1 beyond its interval is refused (the shots are likely swapped)."""
    t_all = np.clip(q.t4, 0, None) ** 0.25
    t_lo, t_hi = np.clip(q.lo4, 0, None) ** 0.25, np.clip(q.hi4, 0, None) ** 0.25
    if t_lo[3] > 1.0:  # above 1 beyond its interval: impossible for a film
        raise InputError(f"t = {t_all[3]:.4f} (95% interval {t_lo[3]:.4f}-{t_hi[3]:.4f}) is above 1; "
                         + str(_swapped_error(names)))
    if t_all[3] > 1.0:
        warnings.append(f"t > 1 ({t_all[3]:.4f}): the bubble region got brighter; check for reflections or flicker")
    if q.blocks_inside < 20:
        warnings.append(f"only {q.blocks_inside} pixel blocks inside the bubble: the interval is approximate")
    return t_all, t_lo, t_hi


# --------------------------------------------------------------------------------------
# The whole calibration
# --------------------------------------------------------------------------------------


def calibrate(
    before, after, circle: tuple[float, float, float] | None = None, *,
    inner_fraction: float = 0.6, exposure_correction: bool = True, max_shift: float | None = None,
    min_cc: float = 0.7, n_boot: int = 2000, seed: int = 0, min_pixels: int = 50,
) -> CalibrationResult:
    """Measure the transmission fraction t from photographs without and with the bubble.

    Parameters
    ----------
    before, after : path, :class:`~bubblefit.io.images.Image` or (H, W, 3) linear array
        The shot without and with the bubble, same fixed camera.
    circle : (cx, cy, r), optional
        The bubble in pixels of ``after`` (pixel centres at +1/2, the convention of
        :class:`bubblefit.model.geometry.OrthographicCamera`); detected when not given.
    inner_fraction : float
        t uses pixels within ``inner_fraction * r`` of the centre (and at least 3 pixels
        inside the rim), away from the oblique rim.
    exposure_correction : bool
        Divide by the after/before ratio of the background outside the bubble.
    max_shift : float, optional
        Largest camera shift accepted, pixels (default: max(8, 10% of the smaller side)).
    min_cc : float
        Smallest ECC correlation for the two shots to count as the same scene.
    n_boot : int
        Bootstrap resamples for the intervals.
    seed : int
        Seed of the bootstrap (results are reproducible).
    min_pixels : int
        Fewest usable pixels inside the bubble.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError
        Unreadable or mismatched files, saturated or black images, two different scenes, no
        bubble, or too few usable pixels inside it; the message is one line.

    Examples
    --------
    A checkered card dimmed by ``t^4`` inside a disc, as a bubble with ``t = 0.97`` would:

    >>> import numpy as np
    >>> import bubblefit as bf
    >>> y, x = np.mgrid[0:96, 0:96] + 0.5
    >>> card = np.where((y // 12 + x // 12) % 2 == 0, 0.7, 0.2)[..., None] * np.ones(3)
    >>> inside = (x - 48) ** 2 + (y - 48) ** 2 < 30 ** 2
    >>> after = np.where(inside[..., None], card * 0.97 ** 4, card)
    >>> result = bf.calibrate(card, after, n_boot=200)
    >>> round(result.t, 4), round(result.bubble["r"])
    (0.97, 30)
    """
    img_b, img_a = load_pair(before, after)
    names = (os.path.basename(img_b.path) or "before", os.path.basename(img_a.path) or "after")
    warnings: list[str] = []
    h, w = img_b.shape
    if min(h, w) < MIN_SIDE:
        raise InputError(f"{names[1]} is {w}x{h} pixels: too small to calibrate (need at least {MIN_SIDE}x{MIN_SIDE})")
    pa, ga = img_a.pixels, gray(img_a.pixels)
    check_exposures(img_b, img_a, names, warnings)
    # 1. registration over the whole frame, 2. the bubble, 3. registration outside it
    reg, circle, given = _registered_bubble(img_b, img_a, circle, max_shift, min_cc, names, warnings)
    # 4. sub-pixel circle and radial fall-off
    (cx, cy, r), prof = _refine(ga, reg, circle, given, seed, warnings)
    radial_model = _radial_model(prof)
    yy, xx = np.mgrid[0:h, 0:w]
    d = np.hypot(xx - cx, yy - cy)
    rho = d / r
    # 5. the robust ratio inside over the ratio outside, per channel; 6. the index
    used = _inner_pixels(reg, d, r, inner_fraction, min_pixels)
    q = _t4_ratio(img_b, pa, ga, reg, used, d >= 1.2 * r + 3, rho, radial_model, exposure_correction, n_boot, seed,
                  warnings)
    t_all, t_lo, t_hi = _t_from_t4(q, names, warnings)
    beta, beta_se = prof["beta"], prof["beta_stderr"]
    n_film, n_se, n_ci = _n_film(radial_model, beta, beta_se, float(q.t4[3]), float(q.lo4[3]), float(q.hi4[3]),
                                 warnings)
    radial = {"model": radial_model, "beta": float(beta), "beta_stderr": float(beta_se), "n_shape": float(q.n_shape),
              **{k: float(prof[k]) for k in ("r_stderr", "noise")}, "n_rim_pixels": int(prof["n_rim_pixels"])}
    ratio_map = np.where(reg.usable, ga / np.where(reg.usable, reg.gray_before, 1.0) / q.k_out[3], np.nan)
    rim = reg.usable & (rho >= 0.75) & (rho <= 0.97)
    return CalibrationResult(
        t=float(t_all[3]), t_rgb=[float(v) for v in t_all[:3]], t4=float(q.t4[3]),
        t_ci95=[float(t_lo[3]), float(t_hi[3])],
        t_rgb_ci95=[[float(t_lo[c]), float(t_hi[c])] for c in range(3)],
        t4_ci95=[float(q.lo4[3]), float(q.hi4[3])],
        bubble={"cx": float(cx) + 0.5, "cy": float(cy) + 0.5, "r": float(r)},
        bubble_source="given" if given else "detected", pixels_used=int(used.sum()),
        shift_px=[float(reg.shift[0]), float(reg.shift[1])], registration_cc=float(reg.cc),
        exposure_ratio=float(q.k_out[3]), exposure_corrected=q.exposure_corrected, radial=radial,
        n_film=n_film, n_film_stderr=n_se, n_film_ci95=n_ci, t_fresnel_corrected=q.fresnel_corrected,
        inner_fraction=inner_fraction, warnings=warnings, image_size=[int(w), int(h)],
        t4_model_stderr=float(q.model_sd[3]),
        inputs={"before": img_b.path, "after": img_a.path},
        maps={"ratio": ratio_map, "used": used, "rim": rim, "after": pa},
    )
