"""The view a photo was taken with: its field of view, where it came from, and the
perspective camera that the bubble's disc then fixes.

A photo fit needs the camera's rays. An orthographic view (parallel rays) is what the fit
has always used; a real lens diverges, and the incidence angles on the film, hence its
colours, change with the field of view. The user knows the view as a field of view, a
focal length on a sensor, or a 35 mm equivalent focal length; a camera writes the last
two into the file's EXIF. :func:`resolve_view` turns these into one :class:`View`
(``kind``, horizontal ``fov_deg``, ``source``); :func:`perspective_from_disc` then builds
the pinhole camera from the field of view and the disc found in the photo, in closed form.

When nothing says what the view was, the fit fits the view's divergence
``u = tan(fov / 2)`` (:func:`divergent_rays`: the rays are smooth in ``u`` through the
orthographic view, ``u = 0``), bracketed by the orthographic view and a plausible lens
(:data:`ASSUMED_FOCAL_35MM`); where the photo does not constrain it, it widens its error
bars by what that lens would change (:mod:`bubblefit.inverse._view`, ``docs/camera-view.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..errors import InputError
from ..model.geometry import disc_angles, divergent_rays

__all__ = ["View", "ViewKind", "ViewSource", "ASSUMED_FOCAL_35MM", "FULL_FRAME_DIAGONAL_MM", "fov_from_focal",
           "fov_from_35mm", "view_from_exif", "resolve_view", "assumed_lens", "outline_axes",
           "perspective_from_disc", "scene_view", "ORTHOGRAPHIC", "divergent_rays", "divergence", "fov_of_divergence",
           "disc_angles"]

ViewKind = Literal["orthographic", "perspective"]
#: Where the view came from: a command-line option (or :class:`~bubblefit.inverse.fit.FitOptions`),
#: the photo's EXIF, a scene file's camera, the photo itself (``fitted``: the divergence
#: fitted when nothing stated the view), or nothing (``assumed``: orthographic, with the
#: error bars widened).
ViewSource = Literal["option", "EXIF", "scene", "fitted", "assumed"]

#: The diagonal of a 36 x 24 mm frame, mm: a "35 mm equivalent" focal length gives the
#: angle of view across the diagonal (CIPA DC-008, EXIF 2.3 ``FocalLengthIn35mmFilm``).
FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)

#: The lens assumed when nothing says what the view was: a 50 mm focal length in 35 mm
#: terms, the "normal" lens (a field of view near 47 degrees on the diagonal). Phones
#: (about 26 mm) are wider; telephoto and macro views of a bubble narrower. It is not
#: fitted to any photo: it sets the size of the error a silent orthographic view risks.
ASSUMED_FOCAL_35MM = 50.0

#: Largest field of view taken (degrees across the width): a pinhole camera's image plane
#: cannot hold 180 degrees, and a fisheye is not a pinhole.
MAX_FOV_DEG = 170.0


@dataclass(frozen=True)
class View:
    """The camera's view of a photo.

    Attributes
    ----------
    kind : ViewKind
        ``orthographic`` (parallel rays) or ``perspective`` (a pinhole).
    fov_deg : float or None
        Angle of view across the image's width, degrees (None for an orthographic view).
    source : ViewSource
        Where it came from.
    detail : str
        How it was worked out, in words (e.g. "50 mm on a 36 mm wide sensor").
    """

    kind: ViewKind = "orthographic"
    fov_deg: float | None = None
    source: ViewSource = "assumed"
    detail: str = ""

    def __post_init__(self):
        if self.kind not in ("orthographic", "perspective"):
            raise InputError(f"a view is orthographic or perspective, got {self.kind!r}")
        if self.kind == "perspective":
            fov = self.fov_deg
            if fov is None or not (isinstance(fov, (int, float)) and 0.0 < fov <= MAX_FOV_DEG):
                raise InputError(f"a perspective view needs a field of view in (0, {MAX_FOV_DEG:g}] degrees, "
                                 f"got {fov!r}")

    def to_json(self) -> dict:
        """The JSON's ``camera`` record: ``kind``, ``fov_deg``, ``source``, ``detail``."""
        return {"kind": self.kind, "fov_deg": None if self.fov_deg is None else float(self.fov_deg),
                "source": self.source, "detail": self.detail}


#: An orthographic view stated by the user (``--fov 0``): parallel rays, e.g. a telecentric
#: lens, a bubble photographed from far away, or a photo rendered with such a camera.
ORTHOGRAPHIC = View("orthographic", None, "option", "parallel rays, as stated")


def fov_from_focal(focal_mm: float, sensor_width_mm: float) -> float:
    """Angle of view across the width (degrees) of a pinhole with focal length ``focal_mm``
    on a sensor ``sensor_width_mm`` wide: ``2 atan(w / 2f)``.

    References
    ----------
    R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed.,
    Cambridge University Press, 2004, sec. 6.1 (the pinhole camera).
    """
    if not (focal_mm > 0 and sensor_width_mm > 0 and math.isfinite(focal_mm) and math.isfinite(sensor_width_mm)):
        raise InputError(f"a focal length and a sensor width must be positive millimetres, got {focal_mm} and "
                         f"{sensor_width_mm}")
    return math.degrees(2.0 * math.atan(sensor_width_mm / (2.0 * focal_mm)))


def fov_from_35mm(focal_35mm: float, width: int, height: int) -> float:
    """Angle of view across the width (degrees) of a ``width x height`` photo from its 35 mm
    equivalent focal length.

    The equivalent focal length gives the full frame's diagonal angle,
    ``tan(d/2) = 43.27 mm / (2 f35)``; the image's width is ``W / hypot(W, H)`` of its
    diagonal on the image plane, so ``tan(h/2) = tan(d/2) W / hypot(W, H)`` for any aspect
    ratio.

    References
    ----------
    CIPA DC-008-2019 (Exif 2.32), ``FocalLengthIn35mmFilm``; ISO 516 on angles of view.
    """
    if not (focal_35mm > 0 and math.isfinite(focal_35mm)):
        raise InputError(f"a 35 mm equivalent focal length must be positive millimetres, got {focal_35mm}")
    tan_d = FULL_FRAME_DIAGONAL_MM / (2.0 * focal_35mm)
    return math.degrees(2.0 * math.atan(tan_d * width / math.hypot(width, height)))


def _number(metadata: dict, key: str) -> float | None:
    v = metadata.get(key)
    if isinstance(v, (list, tuple)) and len(v) == 1:
        v = v[0]
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def view_from_exif(metadata: dict, width: int, height: int) -> View | None:
    """The view the photo's EXIF states, or None.

    ``Exif:FocalLengthIn35mmFilm`` (:func:`fov_from_35mm`) first; else ``Exif:FocalLength``
    with the sensor's width from ``Exif:FocalPlaneXResolution`` (pixels per
    ``Exif:FocalPlaneResolutionUnit``: 2 inch, 3 cm, 4 mm) and the recorded image width
    (``Exif:PixelXDimension``, else the photo's). OpenImageIO names the tags so.
    """
    if not metadata:
        return None
    f35 = _number(metadata, "Exif:FocalLengthIn35mmFilm")
    if f35 is not None:
        return View("perspective", fov_from_35mm(f35, width, height), "EXIF",
                    f"FocalLengthIn35mmFilm {f35:g} mm")
    focal, xres = _number(metadata, "Exif:FocalLength"), _number(metadata, "Exif:FocalPlaneXResolution")
    if focal is None or xres is None:
        return None
    unit_mm = {2: 25.4, 3: 10.0, 4: 1.0}.get(int(_number(metadata, "Exif:FocalPlaneResolutionUnit") or 2))
    if unit_mm is None:
        return None
    pixels = _number(metadata, "Exif:PixelXDimension") or float(width)
    sensor = pixels / xres * unit_mm
    return View("perspective", fov_from_focal(focal, sensor), "EXIF",
                f"FocalLength {focal:g} mm on a {sensor:.3g} mm wide sensor (FocalPlaneXResolution)")


def resolve_view(*, fov_deg: float | None = None, focal_length_mm: float | None = None,
                 sensor_width_mm: float | None = None, focal_length_35mm: float | None = None,
                 metadata: dict | None = None, width: int, height: int) -> View:
    """The :class:`View` of a ``width x height`` photo: the options first (``fov_deg``; 0
    states an orthographic view), then the file's EXIF (``metadata``), else an assumed
    orthographic view. One-line :class:`InputError` for options that conflict or lack a
    part (a focal length without its sensor)."""
    given = [n for n, v in (("--fov", fov_deg), ("--focal-length", focal_length_mm),
                            ("--focal-length-35mm", focal_length_35mm)) if v is not None]
    if len(given) > 1:
        raise InputError(f"give the view once: {' and '.join(given)} both set it")
    if sensor_width_mm is not None and focal_length_mm is None:
        raise InputError("--sensor-width needs --focal-length")
    if fov_deg is not None:
        if fov_deg == 0:
            return ORTHOGRAPHIC
        if not 0 < fov_deg <= MAX_FOV_DEG:
            raise InputError(f"--fov must lie in (0, {MAX_FOV_DEG:g}] degrees (0 for an orthographic view), "
                             f"got {fov_deg}")
        return View("perspective", float(fov_deg), "option", f"--fov {fov_deg:g}")
    if focal_length_mm is not None:
        if sensor_width_mm is None:
            raise InputError("--focal-length needs --sensor-width (the sensor's width in mm), or give "
                             "--focal-length-35mm instead")
        return View("perspective", fov_from_focal(focal_length_mm, sensor_width_mm), "option",
                    f"{focal_length_mm:g} mm on a {sensor_width_mm:g} mm wide sensor")
    if focal_length_35mm is not None:
        return View("perspective", fov_from_35mm(focal_length_35mm, width, height), "option",
                    f"{focal_length_35mm:g} mm in 35 mm terms")
    return view_from_exif(metadata or {}, width, height) or View("orthographic", None, "assumed",
                                                                    "no field of view given or in the file")


def assumed_lens(width: int, height: int) -> View:
    """The plausible lens an assumed view is compared with: :data:`ASSUMED_FOCAL_35MM` in 35 mm
    terms (:func:`fov_from_35mm`)."""
    return View("perspective", fov_from_35mm(ASSUMED_FOCAL_35MM, width, height), "assumed",
                f"a {ASSUMED_FOCAL_35MM:g} mm lens in 35 mm terms, compared with the orthographic view")


def outline_axes(theta: float, alpha: float, focal_px: float) -> tuple[float, float, float]:
    """``(rho, a, b)`` of the ellipse a sphere projects to through a pinhole: its centre's
    distance from the principal point, its semi-axis along that radial direction and the
    one across it (pixels), for a sphere whose centre lies ``theta`` off the optical axis
    and subtends the half-angle ``alpha`` (radians), with focal length ``focal_px``.

    The camera sees the sphere as the cone of rays tangent to it: apex at the pinhole,
    axis toward the centre, half-angle ``alpha`` with ``sin(alpha) = R / D``. In the plane
    holding the optical axis and the cone's axis, the cone's two generators meet the
    image plane at ``f tan(theta - alpha)`` and ``f tan(theta + alpha)``: the radial axis's
    ends. So ``rho = f (tan(theta+alpha) + tan(theta-alpha)) / 2`` and
    ``a = f (tan(theta+alpha) - tan(theta-alpha)) / 2 = f sin(alpha) cos(alpha) / (cos^2 theta - sin^2 alpha)``.
    Across it, the cone ``(v . u)^2 = |v|^2 cos^2 alpha`` (``v = (x, y, f)``,
    ``u = (sin theta, 0, cos theta)``) at ``x = rho`` gives
    ``b = f sin(alpha) / sqrt(cos^2 theta - sin^2 alpha)``. On the axis both are
    ``f tan(alpha)``.

    References
    ----------
    R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2004,
    sec. 8.3 (the image of a quadric's outline is a conic: the cone tangent to it).
    """
    c2 = math.cos(theta) ** 2 - math.sin(alpha) ** 2
    if c2 <= 0:
        raise InputError("the bubble's outline reaches the camera's horizon: not a pinhole's view")
    lo, hi = math.tan(theta - alpha), math.tan(theta + alpha)
    return focal_px * (hi + lo) / 2, focal_px * (hi - lo) / 2, focal_px * math.sin(alpha) / math.sqrt(c2)


def perspective_from_disc(disc: tuple, width: int, height: int, fov_deg: float, radius: float = 1.0):
    """``(camera, center, radius)``: the pinhole camera looking along -z (up +y, the frame an
    environment map is aligned with) that sees a sphere of ``radius`` at ``center`` as the
    disc ``(cx, cy, r)`` (pixels, pixel centres at +1/2) of a ``width x height`` photo with
    the horizontal field of view ``fov_deg``.

    The disc found in a photo is the circle that best fits the sphere's outline, an
    ellipse (:func:`outline_axes`) whose centre lies ``rho`` from the principal point
    ``(W/2, H/2)`` at focal length ``f = W / (2 tan(fov/2))`` pixels. A least-squares
    circle through a near-round ellipse has its centre and the radius ``(a + b) / 2`` (to
    first order in the eccentricity). Inverting :func:`outline_axes` for a radial semi-axis
    ``a`` is closed form:

    ``theta + alpha = atan((rho + a) / f)``,  ``theta - alpha = atan((rho - a) / f)``;

    starting from ``a = r``, ``a = 2 r / (1 + b/a)`` with ``b/a = sqrt(cos^2 theta - sin^2 alpha) / cos alpha``
    at the previous angles, twice (each pass squares the relative error, of order
    ``sin^2 theta / 2``). The sphere's centre then lies at the distance
    ``D = R / sin(alpha)`` along the direction ``theta`` off the axis, toward the disc's
    centre. The sphere is placed at the origin and the camera at ``-D u``.

    References
    ----------
    R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2004,
    sec. 6.1 and 8.3; I. Kasa, IEEE Trans. Instrum. Meas. 25(1), 1976 (the circle fitted).
    """
    from ..model.geometry import PerspectiveCamera

    cx, cy, r = (float(v) for v in disc)
    if not r > 0:
        raise InputError(f"the bubble's disc needs a positive radius, got {r}")
    u_div = math.tan(math.radians(fov_deg) / 2.0)
    ux, uy = cx - width / 2.0, height / 2.0 - cy  # image plane, +y up
    rho = math.hypot(ux, uy)
    ex, ey = (ux / rho, uy / rho) if rho > 0 else (1.0, 0.0)
    theta, alpha = (float(v) for v in disc_angles(rho, r, 2.0 * u_div / width, np))
    if not (0 < alpha < math.pi / 2 and math.cos(theta) ** 2 > math.sin(alpha) ** 2):
        raise InputError(f"a disc of radius {r:.1f} px at ({cx:.1f}, {cy:.1f}) cannot be a sphere's outline "
                         f"in a {fov_deg:g} degree view")
    dist = radius / math.sin(alpha)
    u = (math.sin(theta) * ex, math.sin(theta) * ey, -math.cos(theta))  # toward the sphere's centre
    origin = tuple(-dist * c for c in u)
    target = (origin[0], origin[1], origin[2] - 1.0)
    camera = PerspectiveCamera(int(width), int(height), origin=origin, target=target, up=(0.0, 1.0, 0.0),
                               fov_deg=float(fov_deg))
    return camera, (0.0, 0.0, 0.0), float(radius)


def divergence(fov_deg: float | None) -> float:
    """The view's divergence ``u = tan(fov / 2)`` of a horizontal field of view (0 for an
    orthographic view, ``fov_deg`` None or 0): the half-width of the image plane at unit
    focal length (Hartley and Zisserman 2004, sec. 6.1)."""
    return 0.0 if not fov_deg else math.tan(math.radians(float(fov_deg)) / 2.0)


def fov_of_divergence(u: float) -> float:
    """The horizontal field of view (degrees) of the divergence ``u``: ``2 atan(u)``
    (:func:`divergence` inverted)."""
    return math.degrees(2.0 * math.atan(float(u)))


def scene_view(scene) -> View | None:
    """The view a scene file's ``[camera]`` states, or None when it states none (no
    ``type`` and no ``disc``): ``perspective`` with its ``fov_deg``, or ``orthographic``."""
    if scene is None:
        return None
    cam = scene.table("camera")
    if cam.get("type") == "perspective":
        return View("perspective", float(cam.get("fov_deg", 35.0)), "scene", "the scene file's perspective camera")
    if "type" in cam or "disc" in cam:
        return View("orthographic", None, "scene", "the scene file's orthographic camera")
    return None
