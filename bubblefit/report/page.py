"""The HTML page of one fit: verdict, figures, parameter table and how to read them.

:func:`write_fit_page` is the one page writer: ``bubblefit report`` calls it with the
files a fit wrote (:func:`load_report_inputs`), the demo with its arrays and its table of
true against recovered values.
"""

from __future__ import annotations

import html
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["ReportData", "load_report_inputs", "write_fit_page", "PAGE_FILES", "parameter_rows",
           "verdict_lines"]

#: Every file the page may write into its folder.
PAGE_FILES = ("index.html", "photo_render.png", "residual.png", "thickness.png", "profile.png", "fit.json")

#: Parameters that :data:`bubblefit.inverse.PARAMETERS` does not describe (they are derived or given).
_OTHER = {"f": ("", "r_d / r_s, diffuse over specular reflectance (the paper's f, see below)"),
          "n_film": ("", "film index n_g at 589.3 nm")}


@dataclass
class ReportData:
    """What a page shows: the fit's JSON and its images (linear arrays, or None)."""

    fit: dict
    photo: np.ndarray | None = None
    render: np.ndarray | None = None
    residual: np.ndarray | None = None
    thickness: np.ndarray | None = None
    thickness_stderr: np.ndarray | None = None
    source: str | None = None
    files: list = field(default_factory=list)

    def inputs(self) -> list:
        """The files the page was made from (for the command's output guard)."""
        return [self.source, *self.files]


def load_report_inputs(path: str | os.PathLike) -> ReportData:
    """Read a ``bubblefit fit --json`` result and the images it names (``photo`` and
    ``outputs``); one clear :class:`InputError` when it is not a fit result or a file is missing."""
    from ..io.fitresult import named_path, read_fit_result
    from ..io.images import read_image

    fit = read_fit_result(path)
    data = ReportData(fit=fit, source=str(path))
    outputs = fit.get("outputs") or {}
    for attr, key, what in (("photo", None, "photo"), ("render", "render", "render"),
                            ("residual", "residual", "residual"), ("thickness", "thickness", "thickness map"),
                            ("thickness_stderr", "thickness_stderr", "thickness standard error map")):
        used = named_path(fit.get("photo") if key is None else outputs.get(key), path, what)
        if used is not None:
            img = read_image(used, allow_nan=attr.startswith("thickness")).pixels
            setattr(data, attr, img[..., 0] if attr.startswith("thickness") else img[..., :3])
            data.files.append(used)
    return data


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "&ndash;"
    return f"{v:.4g}"


def parameter_rows(fit: dict) -> list[dict]:
    """One row per reported parameter: name, value, standard error (or why none), unit, meaning."""
    from ..inverse import PARAMETERS

    held = {h["name"]: h["reason"] for h in fit.get("held") or []}
    rows = []
    for name, value in fit["params"].items():
        err = fit["stderr"].get(name)
        unit, meaning = _OTHER.get(name, ("", ""))
        if name in PARAMETERS:
            unit, meaning = PARAMETERS[name].unit, PARAMETERS[name].reference
        if err is not None and math.isfinite(err):
            why = ""
        elif name == "n_film":
            why = "given"
        else:
            why = held.get(name) or (held.get("split") if name in ("f", "r_d", "r_s") else None)
            why = f"held: {why}" if why else "no standard error: the photo does not constrain it"
        rows.append({"name": name, "value": value, "stderr": err if not why else None, "unit": unit,
                     "meaning": meaning, "note": why})
    return rows


def verdict_lines(fit: dict) -> list[str]:
    """The fit's verdict in words: ok, how the solver ended, the misfit, each warning."""
    ok = "yes" if fit.get("ok") else "NO"
    lines = [f"Fit ok: {ok}.",
             ("The solver converged" if fit.get("converged") else
              f"The solver did NOT converge ({fit.get('status', '')})")
             + f" in {fit.get('iterations', '?')} steps: {fit.get('message', '')}".rstrip(": ")]
    floor = fit.get("model_error_floor")
    chi = fit.get("reduced_chi2")
    chif = fit.get("reduced_chi2_floor")
    if chi is not None:
        lines.append(f"Reduced chi^2 {chi:.3g} from the noise alone; {chif:.3g} with the model-error floor of "
                     f"{(floor or 0):.0%} of the signal (ok needs at most 3).")
    out = fit.get("outlier_fraction")
    if out:
        lines.append(f"{out:.2%} of the fitted pixels are outliers (chi^2 over 30 with the floor); without them "
                     f"the reduced chi^2 is {fit.get('reduced_chi2_inliers', float('nan')):.3g}.")
    return lines


EXPLAIN = """<h2>How to read this page</h2>
<dl>
<dt>ok</dt><dd>The fit is trusted only when the solver met its tolerances, the bubble's disc was found or given,
no parameter sits at a bound, and the photo is explained: its reduced chi<sup>2</sup> with the model-error floor is
at most 3. Otherwise each reason is listed above as a warning.</dd>
<dt>f</dt><dd>The ratio of the film's diffuse to its specular reflectance, <i>f</i> = <i>r<sub>d</sub></i> /
<i>r<sub>s</sub></i>. The paper calls it the ratio between the specular and diffuse components and uses
<i>f</i> = 0.3, a mostly mirror-like film. With eq. (14), <i>r<sub>d</sub></i> + <i>r<sub>s</sub></i> =
1 &minus; <i>t</i>, where <i>t</i> is what one interface transmits. In the physical model Fresnel's equations set
<i>r<sub>s</sub></i>, and <i>f</i> follows from the fitted <i>r<sub>d</sub></i>.</dd>
<dt>model-error floor</dt><dd>Noise alone would give a perfect model a reduced chi<sup>2</sup> near 1. No model
of a real film is perfect, so before judging the fit each pixel's noise is widened by a floor of
{floor} of its signal: a model that is right to within a few percent passes. Both figures are shown.
Every thickness's standard error also carries {tme} nm in quadrature, the scatter found against independent
renderers that no residual shows.</dd>
<dt>residual</dt><dd>Photo minus fitted render, averaged over R, G and B, in the photo's linear units (1 is the
file's white). Red: the photo is brighter than the model; blue: darker. Structure, not noise, says what the
model misses (often the sun's glint, which one ray per pixel cannot resolve).</dd>
<dt>standard errors</dt><dd>One standard deviation. From the noise, widened when the residual says the noise model
is too optimistic (here by a factor {scale}). A parameter without one was held, and the table says why.</dd>
</dl>
"""

CSS = """body{font:16px/1.5 system-ui,sans-serif;max-width:1180px;margin:1.5em auto;padding:0 1em;color:#222}
h1{font-size:1.7em;margin-bottom:.2em} h2{font-size:1.3em;margin-top:1.6em;border-bottom:1px solid #ddd}
.verdict{padding:.8em 1.2em;border-radius:6px;margin:1em 0} .ok{background:#e6f4ea;border:1px solid #7cb987}
.bad{background:#fdecea;border:1px solid #e0837a} .verdict p{margin:.3em 0} .verdict ul{margin:.3em 0}
figure{margin:1em 0} figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{color:#555;font-size:.95em}
.grid{display:grid;grid-template-columns:1fr 1fr;gap:1em} .wide{grid-column:1/-1;text-align:center} @media(max-width:900px){.grid{grid-template-columns:1fr}}
table{border-collapse:collapse;margin:.5em 0} td,th{padding:4px 12px;text-align:left;vertical-align:top}
th{background:#f0f0f0} tr:nth-child(even) td{background:#f8f8f8} td.num{text-align:right;font-variant-numeric:tabular-nums}
dt{font-weight:bold;margin-top:.6em} code{background:#f3f3f3;padding:0 3px}"""


def _profile(data: ReportData, truth_column: tuple | None):
    """``(y, d, sigma, label)`` for the profile plot, or None."""
    fit = data.fit
    p, disc = fit["params"], fit.get("disc")
    tme = float(fit.get("thickness_model_error_nm") or 0.0)
    if data.thickness is not None and disc:
        h = data.thickness.shape[0]
        col = int(np.clip(round(disc["cx"] - 0.5), 0, data.thickness.shape[1] - 1))
        y = -(np.arange(h) + 0.5 - disc["cy"]) / disc["r"]
        se = None if data.thickness_stderr is None else data.thickness_stderr[:, col]
        if se is None and fit["thickness"] == "drainage":
            return _drainage(fit, y, tme)
        return y, data.thickness[:, col], se, "fitted (centre column of the map)"
    if fit["thickness"] == "drainage":
        return _drainage(fit, np.linspace(-1, 1, 201), tme)
    if fit["thickness"] == "constant" and p.get("thickness_nm") is not None:
        y = np.linspace(-1, 1, 3)
        s = fit["stderr"].get("thickness_nm")
        return (y, np.full(3, p["thickness_nm"]), None if s is None else np.full(3, s),
                "fitted (constant film)")
    return None


def _drainage(fit: dict, y: np.ndarray, tme: float):
    from .figures import drainage_band

    names = ("top_nm", "bottom_nm", "exponent")
    p = fit["params"]
    cov = None
    c = fit.get("covariance")
    if c and all(n in c["names"] for n in names):
        idx = [c["names"].index(n) for n in names]
        m = np.array([[np.nan if v is None else v for v in row] for row in c["matrix"]], np.float64)
        cov = m[np.ix_(idx, idx)]
    d, s = drainage_band(y, tuple(p[n] for n in names), cov, tme)
    return y, d, s, "fitted drainage profile"


def write_fit_page(data: ReportData, out: str | os.PathLike, *, title: str = "bubblefit: fit report",
                   intro_html: str = "", extra_html: str = "", truth_column: tuple | None = None,
                   photo_title: str = "photo") -> Path:
    """Write ``index.html``, its figures and ``fit.json`` into the folder ``out`` (created).

    ``intro_html`` goes under the title, ``extra_html`` after the parameter table (the
    demo's true-against-recovered table); ``truth_column`` = ``(y, d)`` draws the true
    profile in the profile plot.
    """
    from ..io.atomic import write_json, write_text
    from . import figures

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fit = data.fit
    esc = html.escape
    figs = []
    disc = fit.get("disc")
    if data.photo is not None or data.render is not None:
        figures.photo_render_figure(out / "photo_render.png", data.photo, data.render, disc, photo_title)
        figs.append(("photo_render.png", "The photo and the fitted render, as the file shows them (sRGB); "
                                         "the dotted circle is the fitted disc.", True))
    if data.residual is not None:
        figures.residual_figure(out / "residual.png", data.residual, fit.get("residual_rms"))
        figs.append(("residual.png", "Photo minus render, averaged over R, G and B, in the photo's linear "
                                     "units (the colour bar); the scale is symmetric about 0.", False))
    if data.thickness is not None:
        figures.thickness_figure(out / "thickness.png", data.thickness, data.thickness_stderr, disc)
        figs.append(("thickness.png", "Front-film thickness per pixel and, for a map, its standard error "
                                      "(colour bars in nm; 1st to 99th percentile).", data.thickness_stderr is not None))
    prof = _profile(data, truth_column)
    if prof is not None:
        y, d, s, label = prof
        figures.profile_figure(out / "profile.png", y, d, s, label, truth_column)
        figs.append(("profile.png", "Thickness against height on the bubble, with a band of one standard "
                                    "error (it includes the thickness model error).", False))
    write_json(out / "fit.json", fit)

    ok = bool(fit.get("ok"))
    warns = fit.get("warnings") or []
    vlines = verdict_lines(fit)
    verdict = (f"<div class='verdict {'ok' if ok else 'bad'}'><p><b>{esc(vlines[0])}</b></p>"
               + "".join(f"<p>{esc(v)}</p>" for v in vlines[1:])
               + ("<p>Warnings:</p><ul>" + "".join(f"<li>{esc(w)}</li>" for w in warns) + "</ul>" if warns
                  else "<p>No warnings.</p>") + "</div>")
    fig_html = "<div class='grid'>" + "".join(
        f"<figure{' class=wide' if wide else ''}><img src='{f}' alt='{esc(c)}'>"
        f"<figcaption>{esc(c)}</figcaption></figure>" for f, c, wide in figs
    ) + "</div>" if figs else ("<p>No images: run <code>bubblefit fit ... -o PREFIX --json FIT.json</code> "
                               "so that the result names its render, residual and maps.</p>")
    rows = "\n".join(
        f"<tr><td><code>{esc(r['name'])}</code></td><td class='num'>{_fmt(r['value'])}</td>"
        f"<td class='num'>{_fmt(r['stderr']) if r['stderr'] is not None else ''}</td><td>{esc(r['unit'])}</td>"
        f"<td>{esc(r['note'] or r['meaning'])}</td></tr>" for r in parameter_rows(fit))
    colour = fit.get("colour") or {}
    dsc = "" if not disc else (f"disc centre ({disc['cx']:.2f}, {disc['cy']:.2f}) px, radius {disc['r']:.2f} px"
                               + (" (refined by the fit)" if fit.get("disc_stderr") else ""))
    details = [f"Model: <b>{esc(str(fit['model']))}</b>; thickness: <b>{esc(str(fit['thickness']))}</b>",
               f"illuminant {esc(str(colour.get('illuminant', 'D65')))}, camera response "
               f"{esc(str(colour.get('response', 'srgb')))}", dsc,
               f"{fit.get('pixels_used', '?')} pixels fitted in {fit.get('time_s', float('nan')):.1f} s"]
    floor = fit.get("model_error_floor")
    explain = EXPLAIN.format(floor=f"{floor:.0%}" if floor else "a few percent",
                             tme=f"{fit.get('thickness_model_error_nm', 0):g}",
                             scale=f"{fit.get('stderr_scale', 1.0):.3g}")
    src = "" if not data.source else f"Result of <code>{esc(str(data.source))}</code>: "
    doc = f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width,initial-scale=1">
<title>{esc(title)}</title><style>{CSS}</style></head>
<body><h1>{esc(title)}</h1>
<p>{src}{' &middot; '.join(d for d in details if d)}.</p>
{intro_html}
{verdict}
<h2>Images</h2>
{fig_html}
<h2>Parameters</h2>
<table><tr><th>parameter</th><th>value</th><th>standard error</th><th>unit</th><th>meaning, or why it was held</th></tr>
{rows}</table>
{extra_html}
{explain}
<p>Machine-readable: <a href="fit.json">fit.json</a>.</p>
</body></html>
"""
    page = out / "index.html"
    write_text(page, doc)
    return page
