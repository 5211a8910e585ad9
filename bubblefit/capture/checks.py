"""The checks of a capture protocol.

Each check adds :class:`CheckResult` rows (PASS, FAIL, WARN or SKIP, with a reason a
person can act on) to a :class:`CaptureReport`; :func:`bubblefit.capture.protocols.check_capture`
runs the ones a protocol's spec asks for. What each check implements is listed in
:mod:`bubblefit.capture.protocols`; see ``docs/design.md``, "Capture protocols".
"""

from __future__ import annotations

import fnmatch
import math
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..io.images import Image
from .ball import ball_mask, find_ball
from .hdr import file_clip_level, merge_exposures
from .measure import (
    background_ratio,
    difference_mask,
    fmt_value,
    metadata_value,
    measure_shift,
    same_value,
    saturated_mask,
)
from .report import FAIL, PASS, SKIP, WARN, CaptureReport

__all__ = [
    "IMAGE_EXTENSIONS",
    "match_roles",
    "check_metadata",
    "check_pair",
    "check_difference_subject",
    "check_difference_pairs",
    "check_brackets",
    "check_bracket_registration",
    "check_ball",
    "check_frame_saturation",
]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr")


# --------------------------------------------------------------------------------------
# The checks
# --------------------------------------------------------------------------------------


def match_roles(folder: Path, spec: dict, report: CaptureReport) -> dict[str, list[Path]] | None:
    """``files``: the images of ``folder`` matched to the spec's roles (case-insensitive globs,
    any of a role's patterns; each file goes to the first role that matches it). Returns
    role -> files, or None when a role has too few or too many."""
    names = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    images = [p for p in names if p.suffix.lower() in IMAGE_EXTENSIONS]
    if not images:
        raise InputError(f"no images in {folder} (looked for {', '.join(IMAGE_EXTENSIONS)})")
    roles: dict[str, list[Path]] = {}
    problems = []
    taken: set[Path] = set()
    for r in spec["files"]:
        pats = [p.lower() for p in r["patterns"]]
        hits = [p for p in images if any(fnmatch.fnmatch(p.name.lower(), q) for q in pats) and p not in taken]
        taken.update(hits)
        roles[r["role"]] = hits
        lo, hi = int(r["min_count"]), int(r["max_count"])
        if len(hits) < lo:
            problems.append(f"missing {r['role']!r} image ({lo} needed, file names {r['pattern']})"
                            if len(hits) == 0 else
                            f"{len(hits)} {r['role']!r} image(s), at least {lo} needed ({r['pattern']})")
        elif hi >= 0 and len(hits) > hi:
            problems.append(f"{len(hits)} {r['role']!r} images, at most {hi} expected ({r['pattern']})")
    report.files = {k: [p.name for p in v] for k, v in roles.items()}
    extra = [p.name for p in images if p not in taken]
    if problems:
        report.add("files", FAIL, "; ".join(problems))
        return None
    msg = ", ".join(f"{k}: {len(v)}" for k, v in roles.items())
    if extra:
        report.add("files", WARN, f"{msg}; ignored {len(extra)} file(s) matching no role: {', '.join(extra[:4])}")
    else:
        report.add("files", PASS, msg)
    return roles


def check_metadata(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> None:
    meta = spec.get("metadata", {})
    required = list(meta.get("required", []))
    recommended = list(meta.get("recommended", []))
    missing_req, missing_rec = [], []
    for name, im in imgs.items():
        for key in required:
            if metadata_value(im, key) is None:
                missing_req.append(f"{name}: {key}")
        for key in recommended:
            if metadata_value(im, key) is None:
                missing_rec.append(f"{name}: {key}")
    if missing_req:
        report.add("metadata", FAIL, "missing required metadata (" + "; ".join(missing_req[:6]) + ")")
    elif missing_rec:
        report.add("metadata", WARN, "not recorded, so not checked: " + "; ".join(missing_rec[:6]))
    elif required or recommended:
        report.add("metadata", PASS, "present: " + ", ".join(required + recommended))

    locked = list(meta.get("locked", []))
    if locked and len(imgs) > 1:
        changed, unknown = [], []
        for key in locked:
            vals = {n: metadata_value(im, key) for n, im in imgs.items()}
            known = {n: v for n, v in vals.items() if v is not None}
            if len(known) < len(vals):
                unknown.append(key)
            if len(known) >= 2:
                ref_name, ref = next(iter(known.items()))
                for n, v in known.items():
                    if not same_value(ref, v):
                        changed.append(f"{key} differs ({ref_name}: {fmt_value(key, ref)}, {n}: {fmt_value(key, v)})")
                        break
        if changed:
            report.add("locked", FAIL, "; ".join(changed) + " - lock the camera in manual mode")
        elif unknown:
            report.add("locked", WARN, "cannot check, not recorded in every file: " + ", ".join(unknown))
        else:
            report.add("locked", PASS, "equal in all files: " + ", ".join(locked))

    if meta.get("manual_white_balance", False):
        autos = [n for n, im in imgs.items() if metadata_value(im, "white_balance") == 0]
        unknown = [n for n, im in imgs.items() if metadata_value(im, "white_balance") is None]
        if autos:
            report.add("white_balance", FAIL, f"auto white balance in {', '.join(autos[:4])}: set a fixed (manual) white balance")
        elif unknown:
            report.add("white_balance", WARN, f"white balance not recorded in {', '.join(unknown[:4])}")
        else:
            report.add("white_balance", PASS, "manual white balance in every file")


def check_pair(spec: dict, a: Image, b: Image, an: str, bn: str, report: CaptureReport,
               *, scale_b: float = 1.0) -> tuple[np.ndarray | None, bool]:
    """Photometric and registration checks of a pair; returns (ratio, registered)."""
    checks = spec.get("checks", {})
    ratio = None
    if checks.get("photometric_tolerance") is not None:
        ratio = _check_photometric(spec, a, b, an, bn, report, scale_b=scale_b)
    registered = True
    if checks.get("registration_max_px") is not None:
        registered = _check_registration(spec, a, b, an, bn, report, scale_b=scale_b)
    return ratio, registered


def _check_photometric(spec: dict, a: Image, b: Image, an: str, bn: str, report: CaptureReport,
                       *, scale_b: float) -> np.ndarray:
    """``photometric``: the background (the subject's region left out) has the same exposure
    and white balance in both frames. Returns the background's per-channel ratio."""
    checks = spec["checks"]
    tol = float(checks["photometric_tolerance"])
    ratio = background_ratio(a.pixels, b.pixels * scale_b, tol=float(checks.get("difference_tolerance", 0.04)))
    ratio = np.full(3, np.nan) if ratio is None else ratio
    report.measurements["background_ratio_rgb"] = [float(x) for x in ratio]
    if not np.all(np.isfinite(ratio)):
        report.add("photometric", WARN, f"too few well-exposed background pixels to compare {an} and {bn}")
        return ratio
    dev = np.abs(ratio - 1.0)
    spread = float(ratio.max() / ratio.min() - 1.0)
    if spread > tol:
        report.add("photometric", FAIL,
                   f"white balance changed between {an} and {bn}: background R,G,B ratios "
                   f"{ratio[0]:.3f}, {ratio[1]:.3f}, {ratio[2]:.3f}")
    elif dev.max() > tol:
        stops = math.log2(float(np.mean(ratio)))
        report.add("photometric", FAIL,
                   f"exposure changed between {an} and {bn}: background {float(np.mean(ratio)):.3f}x ({stops:+.2f} stops)")
    else:
        report.add("photometric", PASS, f"background matches within {100 * dev.max():.1f}% per channel")
    return ratio


def _check_registration(spec: dict, a: Image, b: Image, an: str, bn: str, report: CaptureReport,
                        *, scale_b: float) -> bool:
    """``registration``: the camera did not move between the frames (:func:`measure_shift`:
    a shift is reported only when it is clear). Returns whether the pair is registered."""
    checks = spec["checks"]
    lim = float(checks["registration_max_px"])
    reg = measure_shift(a.pixels, b.pixels, scale_b=scale_b, tol=float(checks.get("difference_tolerance", 0.04)),
                        clipped_a=saturated_mask(a), clipped_b=saturated_mask(b))
    report.measurements.setdefault("shift_px", {})[f"{an}->{bn}"] = [reg.dx, reg.dy] if reg.clear else None
    if not reg.clear and reg.mismatch > 0.5:
        report.add("registration", FAIL,
                   f"{bn} does not show the same view as {an}: {100 * reg.mismatch:.0f}% of the background "
                   "differs and no camera shift explains it")
        return False
    if not reg.clear:
        report.add("registration", WARN,
                   f"{100 * reg.mismatch:.0f}% of the background differs between {an} and {bn} but no camera "
                   "shift explains it (something in the scene moved or the light changed): no shift measured")
        return True
    if reg.shift > lim:
        report.add("registration", FAIL,
                   f"{bn} is shifted by ({reg.dx:+.1f}, {reg.dy:+.1f}) px from {an} (limit {lim:g} px): "
                   "the camera moved; use a tripod and a remote release")
        return False
    if reg.shift == 0.0:
        report.add("registration", PASS, f"the background of {bn} matches {an} without a shift")
    else:
        report.add("registration", PASS, f"{bn} within {reg.shift:.2f} px of {an}")
    return True


def check_difference_subject(spec: dict, before: Image, after: Image, bn: str, an: str,
                              ratio, report: CaptureReport, subject: str = "bubble") -> None:
    checks = spec.get("checks", {})
    mask = difference_mask(before.pixels, after.pixels, ratio=ratio,
                           tol=float(checks.get("difference_tolerance", 0.04)))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        report.add("subject", FAIL, f"{an} does not differ from {bn}: no {subject} found")
        return
    big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    region = labels == big
    x, y, w, h, area = stats[big]
    diam = float(max(w, h))
    report.measurements[f"{subject}_bbox_px"] = [int(x), int(y), int(w), int(h)]
    min_d = float(checks.get("min_subject_diameter_px", 0))
    H, W = region.shape
    touches = x == 0 or y == 0 or x + w >= W or y + h >= H
    if diam < min_d:
        report.add("subject", FAIL, f"the {subject} is {diam:.0f} px across, at least {min_d:.0f} px needed: move closer or zoom in")
    elif touches and checks.get("subject_inside_frame", True):
        report.add("subject", FAIL, f"the {subject} touches the frame's edge: frame it whole")
    else:
        report.add("subject", PASS, f"{subject} found, {diam:.0f} px across at ({x + w / 2:.0f}, {y + h / 2:.0f})")
    region = cv2.dilate(region.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    max_frac = float(checks.get("max_saturated_fraction", 0.0))
    bad = []
    for name, im in ((bn, before), (an, after)):
        sat = saturated_mask(im) & region
        frac = sat.sum() / max(region.sum(), 1)
        if sat.any() and frac > max_frac:
            bad.append(f"{int(sat.sum())} saturated pixel(s) inside the {subject} in {name}")
    if bad:
        report.add("saturation", FAIL, "; ".join(bad) + ": shorten the exposure")
    else:
        report.add("saturation", PASS, f"no saturated pixels inside the {subject}")


def check_difference_pairs(spec: dict, roles: dict[str, list[Path]], imgs: dict[str, Image],
                           report: CaptureReport) -> None:
    """Each frame of the spec's second ``pair`` role against the first role's frame:
    photometric, registration, subject and saturation; without the first role's frame, the
    subject is skipped and the frames' saturation is checked instead."""
    checks = spec.get("checks", {})
    subject = checks.get("subject_name", "bubble")
    ra, rb = checks["pair"]
    if not (roles.get(ra) and roles.get(rb)):
        report.add("subject", SKIP, f"no {ra!r} image: the {subject} cannot be located nor checked for saturation")
        check_frame_saturation(spec, imgs, report)
        return
    an = roles[ra][0].name
    for p in roles[rb]:
        bn = p.name
        ratio, registered = check_pair(spec, imgs[an], imgs[bn], an, bn, report)
        if registered:
            check_difference_subject(spec, imgs[an], imgs[bn], an, bn, ratio, report, subject=subject)
        else:
            report.add("subject", SKIP, f"{bn} not checked: the pair is not registered")


def check_brackets(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> list[tuple[str, float]] | None:
    br = spec.get("checks", {}).get("brackets")
    if br is None:
        return None
    times, missing = [], []
    for n, im in imgs.items():
        t = metadata_value(im, "exposure_time")
        if isinstance(t, (int, float)) and t > 0:
            times.append((n, float(t)))
        else:
            missing.append(n)
    if missing:
        report.add("brackets", FAIL, f"no ExposureTime in {', '.join(missing[:4])}: cannot merge the brackets")
        return None
    times.sort(key=lambda x: x[1])
    tv = np.array([t for _, t in times])
    n_min = int(br.get("min_exposures", 3))
    span = float(np.log2(tv.max() / tv.min())) if tv.size else 0.0
    steps = np.diff(np.log2(tv)) if tv.size > 1 else np.array([])
    report.measurements["bracket_stops"] = span
    report.measurements["exposure_times_s"] = [t for _, t in times]
    problems = []
    if tv.size < n_min:
        problems.append(f"{tv.size} exposure(s), at least {n_min} needed")
    if span < float(br.get("min_span_stops", 8)):
        problems.append(f"brackets span {span:.1f} stops, at least {br.get('min_span_stops', 8):g} needed")
    if steps.size and steps.max() > float(br.get("max_step_stops", 3)):
        problems.append(f"a {steps.max():.1f}-stop gap between exposures (at most {br.get('max_step_stops', 3):g})")
    if steps.size and np.any(steps < 0.05):
        problems.append("two exposures have the same exposure time")
    if problems:
        report.add("brackets", FAIL, "; ".join(problems))
    else:
        report.add("brackets", PASS, f"{tv.size} exposures spanning {span:.1f} stops, largest step {steps.max() if steps.size else 0:.1f}")
    return times


def check_bracket_registration(spec: dict, imgs: dict[str, Image], times, report: CaptureReport) -> None:
    """``registration``: consecutive exposures of a bracket show the scene at the same place
    (:func:`measure_shift`, each pair brought to one exposure)."""
    if not times or len(times) < 2 or spec.get("checks", {}).get("registration_max_px") is None:
        return
    lim = float(spec["checks"]["registration_max_px"])
    worst, unclear = (0.0, ""), []
    for (n0, t0), (n1, t1) in zip(times[:-1], times[1:]):
        reg = measure_shift(imgs[n0].pixels, imgs[n1].pixels, scale_b=t0 / t1,
                            clipped_a=saturated_mask(imgs[n0]), clipped_b=saturated_mask(imgs[n1]))
        report.measurements.setdefault("shift_px", {})[f"{n0}->{n1}"] = [reg.dx, reg.dy] if reg.clear else None
        if not reg.clear:
            unclear.append(n1)
        elif reg.shift > worst[0]:
            worst = (reg.shift, f"{n1} is shifted by ({reg.dx:+.1f}, {reg.dy:+.1f}) px from {n0}")
    if worst[0] > lim:
        report.add("registration", FAIL, f"{worst[1]} (limit {lim:g} px): the camera moved between brackets")
    elif unclear:
        report.add("registration", WARN, f"{', '.join(unclear[:3])} differ(s) from the neighbouring exposure "
                                         "but no camera shift explains it: no shift measured")
    else:
        report.add("registration", PASS, f"brackets within {worst[0]:.2f} px of each other")


def check_ball(spec: dict, imgs: dict[str, Image], times, report: CaptureReport) -> None:
    checks = spec.get("checks", {})
    names = list(imgs)
    if times:
        order = [n for n, _ in times]
        tv = [t for _, t in times]
        merged = merge_exposures([imgs[n].pixels for n in order], tv,
                                 saturated=[saturated_mask(imgs[n]) for n in order],
                                 clip_level=[file_clip_level(imgs[n].bit_depth) for n in order]).radiance
    else:
        order = names
        merged = imgs[names[0]].pixels
    try:
        circle = find_ball(merged)
    except InputError as exc:
        report.add("subject", FAIL, f"no mirror ball found ({exc})")
        return
    report.measurements["ball"] = circle.as_dict()
    h, w = merged.shape[:2]
    min_r = float(checks.get("min_ball_radius_px", 0))
    inside = (circle.cx - circle.r >= 0 and circle.cy - circle.r >= 0
              and circle.cx + circle.r <= w and circle.cy + circle.r <= h)
    if circle.r < min_r:
        report.add("subject", FAIL, f"the ball's radius is {circle.r:.0f} px, at least {min_r:.0f} px needed: zoom in")
    elif not inside:
        report.add("subject", FAIL, "the ball is cut by the frame's edge: frame it whole")
    else:
        report.add("subject", PASS, f"mirror ball at ({circle.cx:.1f}, {circle.cy:.1f}), radius {circle.r:.1f} px")
    mask = ball_mask((h, w), circle, shrink=1.0)
    darkest = order[0]
    sat = saturated_mask(imgs[darkest]) & mask
    max_frac = float(checks.get("max_saturated_fraction", 0.0))
    if sat.any() and sat.sum() / max(mask.sum(), 1) > max_frac:
        what = "the darkest exposure" if len(order) > 1 else "the probe"
        report.add("saturation", FAIL, f"{what} ({darkest}) has {int(sat.sum())} saturated pixel(s) inside the ball: "
                                       "add a shorter exposure (or an ND filter) for the sun and lamps")
    else:
        report.add("saturation", PASS, f"no saturated pixels inside the ball in {darkest}")



def check_frame_saturation(spec: dict, imgs: dict[str, Image], report: CaptureReport) -> None:
    lim = spec.get("checks", {}).get("max_frame_saturated_fraction")
    if lim is None:
        return
    bad = []
    for n, im in imgs.items():
        frac = float(saturated_mask(im).mean())
        if frac > float(lim):
            bad.append(f"{n}: {100 * frac:.1f}% of pixels saturated")
    if bad:
        report.add("saturation", FAIL, "; ".join(bad[:4]) + f" (at most {100 * float(lim):.1f}%)")
    else:
        report.add("saturation", PASS, f"at most {100 * float(lim):.1f}% of any frame saturated")
