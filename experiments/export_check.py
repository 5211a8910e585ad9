"""Render what `bubblefit export` writes in each target renderer and compare it with the photo.

For validation cases with a constant or drainage film (experiments/validation/data/): fit
the photo (`bubblefit fit --json -o PREFIX`, as validate.py does), export the fit to every
format, render the export in its renderer, and score the render against the photo by the
median CIEDE2000 (colour-science's ``delta_E``, ``CIE 2000``) over the inner disc (0.8 of
the true radius). Both images are taken as linear sRGB clipped to [0, 1] (the photo is an
8-bit file) and converted to CIELAB under D65.

Yardsticks in the same table: the fit's own render against the photo (what the fit
itself reaches), and the photo against its background photo outside the bubble (1.1 r and
beyond: two noisy 8-bit captures of the same scene, so about sqrt(2) times the floor that
the photo's own noise sets for a noise-free render). Each export's render is also scored
against the fit's own render (``dE00_median_inner_vs_fit_render``): the format's fidelity
to the fit, without the photo's noise.

Renderers (the render venv, experiments/validation/requirements.txt):
  blender  the exported bubble_blender.py, Blender Cycles (CPU) through the `bpy` module
  gltf     bubble.gltf imported by Blender's own glTF importer (mesh, UVs, camera); its
           importer drops KHR_materials_iridescence, so the extension's values (film index,
           thickness minimum/maximum and texture) are put on the imported Principled BSDF's
           thin film as the extension defines them, then rendered in Cycles with the
           world and backplate of the export record
  mitsuba  bubble_mitsuba.xml, Mitsuba 3 (scalar_rgb)
  openpbr  bubble.mtlx rendered by MaterialX's own GLSL renderer (the MaterialX wheel's
           GlslRenderer, FIS environment sampling, ``--spp`` samples per lobe) in the project
           venv, under Xvfb with Mesa's llvmpipe (experiments/openpbr_glsl_render.py: the
           near and far wall of the sphere and the backplate through the renderer's own
           transmittance); its own image, the map seen through the bubble, is scored too
           (``dE00_median_inner_envthrough``), and a diagnostic where each wall transmits
           1 - its reflectance (``dE00_median_inner_conserving``)

    .venv/bin/python experiments/export_check.py [--cases ...] [--spp 64] [--fits DIR]

Writes experiments/results/export/<case>.json and summary.json.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "experiments" / "validation" / "data"
RENDER_PY = Path(os.environ.get("BUBBLEFIT_RENDER_PYTHON", REPO / ".venv-render" / "bin" / "python"))
CASES = ["ref_const300_courtyard_ortho", "ref_drain_lin_courtyard_ortho", "cyc_const500_courtyard_ortho",
         "cyc_drain_lin_sunrise_persp"]

GLTF_IN_CYCLES = r'''
import json, math, os, sys
import bpy
from mathutils import Matrix
gltf, script, out, spp = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
# the export's Blender script builds world, backplate and render settings; its bubble and camera are
# then replaced by what Blender's glTF importer makes of bubble.gltf
ns = {"__file__": script, "__name__": "export_scene"}
src = open(script).read().replace("\nmain(sys.argv", "\n# main(sys.argv")
exec(compile(src, script, "exec"), ns)
sc = ns["build"](spp)
sc.render.threads_mode = "FIXED"; sc.render.threads = 2
for name in ("bubble", "photo camera"):
    bpy.data.objects.remove(bpy.data.objects[name], do_unlink=True)
bpy.ops.import_scene.gltf(filepath=gltf)
doc = json.load(open(gltf))
ext = doc["materials"][0]["extensions"]["KHR_materials_iridescence"]
for ob in bpy.context.scene.objects:
    if ob.type == "CAMERA":
        sc.camera = ob  # as the importer made it from the glTF camera (yfov, aspect ratio)
    if ob.type == "MESH" and ob.name != "backplate":
        mat = ob.data.materials[0]
        nt = mat.node_tree
        pr = [n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"][0]
        pr.inputs["Thin Film IOR"].default_value = ext["iridescenceIor"]
        lo, hi = ext["iridescenceThicknessMinimum"], ext["iridescenceThicknessMaximum"]
        if "iridescenceThicknessTexture" in ext:
            uri = doc["images"][doc["textures"][ext["iridescenceThicknessTexture"]["index"]]["source"]]["uri"]
            import base64, tempfile
            png = os.path.join(tempfile.mkdtemp(), "thickness.png")
            open(png, "wb").write(base64.b64decode(uri.split(",", 1)[1]))
            img = nt.nodes.new("ShaderNodeTexImage"); img.image = bpy.data.images.load(png)
            img.image.colorspace_settings.name = "Non-Color"
            sep = nt.nodes.new("ShaderNodeSeparateColor")
            rng = nt.nodes.new("ShaderNodeMapRange")
            rng.inputs["To Min"].default_value, rng.inputs["To Max"].default_value = lo, hi
            nt.links.new(img.outputs["Color"], sep.inputs["Color"])
            nt.links.new(sep.outputs["Green"], rng.inputs["Value"])
            nt.links.new(rng.outputs["Result"], pr.inputs["Thin Film Thickness"])
        else:
            pr.inputs["Thin Film Thickness"].default_value = hi
sc.render.filepath = out
bpy.ops.render.render(write_still=True)
'''

MITSUBA = r'''
import sys
import mitsuba as mi
mi.set_variant("scalar_rgb")
xml, out, spp = sys.argv[1], sys.argv[2], int(sys.argv[3])
img = mi.render(mi.load_file(xml), spp=spp, seed=1)
mi.util.write_bitmap(out, img)
'''


def lab(rgb: np.ndarray) -> np.ndarray:
    import colour

    xyz = colour.RGB_to_XYZ(np.clip(rgb, 0.0, 1.0), colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])


def delta_e(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    import colour

    return colour.delta_E(lab(a), lab(b), method="CIE 2000")


def read(path) -> np.ndarray:
    from bubblefit.io.images import read_image

    return read_image(path).pixels[..., :3]


def masks(truth: dict, shape) -> tuple[np.ndarray, np.ndarray]:
    h, w = shape[:2]
    d = truth["disc"]
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rr = np.hypot(jj - d["cx"], ii - d["cy"])
    return rr < 0.8 * d["r"], rr > 1.1 * d["r"]


def run_fit(case: str, truth: dict, fits: Path) -> Path:
    js = fits / f"{case}.json"
    if js.exists():
        return js
    thickness = "constant" if truth["thickness"]["profile"] == "constant" else "drainage"
    cdir = DATA / case
    cmd = [sys.executable, "-m", "bubblefit", "fit", str(cdir / "photo.png"), "--envmap", str(DATA / truth["envmap"]),
           "--background", str(cdir / "background.png"), "--thickness", thickness, "--json", str(js),
           "-o", str(fits / case), "--illuminant", truth["illuminant"]]
    if (cdir / "scene.toml").exists():
        cmd += ["--scene", str(cdir / "scene.toml")]
    subprocess.run(cmd, check=True, cwd=REPO)
    return js


def check_case(case: str, out: Path, fits: Path, spp: int, formats=("blender", "gltf", "mitsuba", "openpbr")) -> dict:
    from bubblefit.export import export_bubble, load_fit

    truth = json.loads((DATA / case / "truth.json").read_text())
    js = run_fit(case, truth, fits)
    fit = json.loads(js.read_text())
    cdir = DATA / case
    scene = str(cdir / "scene.toml") if (cdir / "scene.toml").exists() else None
    bubble = load_fit(js, envmap=str(DATA / truth["envmap"]), background=str(cdir / "background.png"), scene=scene)
    photo = read(cdir / "photo.png")
    inner, outer = masks(truth, photo.shape)
    row = {"case": case, "renderer_of_photo": truth["renderer"], "fit": {
        "model": fit["model"], "thickness": fit["thickness"], "ok": fit["ok"], "params": fit["params"]},
        "disc_true": truth["disc"], "inner_pixels": int(inner.sum()), "spp": spp, "formats": {}}
    fit_render = read(fit["outputs"]["render"])
    row["yardstick_fit_render_dE00_median"] = float(np.median(delta_e(photo, fit_render)[inner]))
    row["noise_floor_photo_vs_background_dE00_median_outside"] = float(
        np.median(delta_e(photo, read(cdir / "background.png"))[outer]))
    work = out / "work" / case
    for fmt in formats:
        if fmt == "gltf" and "blender" not in formats:
            export_bubble(bubble, "blender", work / "blender")  # the world and backplate it borrows
        exp = export_bubble(bubble, fmt, work / fmt)
        entry = {"files": [p.name for p in exp.files], "limitations": exp.notes}
        img = work / f"{fmt}.exr"
        t0 = time.perf_counter()
        if fmt == "blender":
            cmd = [str(RENDER_PY), str(exp.main), "--render", str(img), "--samples", str(spp), "--threads", "2"]
        elif fmt == "gltf":
            helper = work / "gltf_in_cycles.py"
            helper.write_text(GLTF_IN_CYCLES)
            blender_dir = work / "blender"
            cmd = [str(RENDER_PY), str(helper), str(exp.main), str(blender_dir / "bubble_blender.py"), str(img),
                   str(spp)]
        elif fmt == "mitsuba":
            helper = work / "mitsuba_render.py"
            helper.write_text(MITSUBA)
            cmd = [str(RENDER_PY), str(helper), str(exp.main), str(img), str(spp)]
        else:
            cmd = openpbr_command(exp.main.parent, img, spp)
            entry["renderer"] = openpbr_renderer()
        res = subprocess.run(cmd, cwd=exp.main.parent, capture_output=True, text=True,
                             env=openpbr_env() if fmt == "openpbr" else None)
        entry["render_seconds"] = round(time.perf_counter() - t0, 1)
        if res.returncode != 0 or not img.exists():
            entry["rendered"] = False
            entry["error"] = (res.stderr or res.stdout).strip().splitlines()[-3:]
        else:
            rend = read(img)
            de = delta_e(photo, rend)
            entry.update(rendered=True, dE00_median_inner=float(np.median(de[inner])),
                         dE00_median_inner_vs_fit_render=float(np.median(delta_e(fit_render, rend)[inner])),
                         dE00_p90_inner=float(np.percentile(de[inner], 90)),
                         dE00_median_outside=float(np.median(de[outer])),
                         mean_ratio_inner=[float(v) for v in rend[inner].mean(0) / photo[inner].mean(0)])
            save_strip(work / f"{fmt}_vs_photo.png", photo, rend)
            for extra in ("envthrough", "conserving"):
                other = img.with_name(f"{img.stem}_{extra}{img.suffix}")
                if other.exists():
                    entry[f"dE00_median_inner_{extra}"] = float(np.median(delta_e(photo, read(other))[inner]))
        row["formats"][fmt] = entry
        print(case, fmt, {k: v for k, v in entry.items() if k.startswith("dE") or k in ("rendered", "error")},
              flush=True)
    return row


def openpbr_command(folder: Path, img: Path, spp: int, *extra: str) -> list[str]:
    """MaterialX's GLSL renderer on the export in ``folder``, under a virtual X screen."""
    return ["xvfb-run", "-a", "-s", "-screen 0 640x480x24", sys.executable,
            str(REPO / "experiments" / "openpbr_glsl_render.py"), str(folder), str(img), "--samples", str(spp), *extra]


def openpbr_env() -> dict:
    """Mesa's software rasteriser (llvmpipe) for the virtual screen's OpenGL."""
    return {**os.environ, "LIBGL_ALWAYS_SOFTWARE": "1", "GALLIUM_DRIVER": "llvmpipe"}


def openpbr_renderer() -> str:
    """The versions that render the OpenPBR export (MaterialX wheel, Mesa)."""
    import MaterialX

    mesa = subprocess.run(["dpkg-query", "-W", "-f", "${Version}", "libgl1-mesa-dri"], capture_output=True,
                          text=True).stdout.strip() or "unknown"
    return f"MaterialX {MaterialX.__version__} GlslRenderer (FIS), Mesa {mesa} llvmpipe, Xvfb"


def rotation_check(out: Path, fits: Path, spp: int, rotation: float = 60.0, fmt: str = "blender") -> dict:
    """The map's rotation and the camera, against bubblefit's own renderer: the ref_const300
    fit with its map turned by ``rotation`` degrees, rendered by `bubblefit render` (physical
    model, no diffuse term) and by the export of ``fmt``; median CIEDE2000 over the inner disc.
    A wrong sign of the turn moves every reflected feature (tens of units).

    ``openpbr`` compares the reflections alone (both with a black backplate: MaterialX's GLSL
    does not take the film's reflection out of the light it transmits, which would hide the
    map's turn behind a brightness difference) and scores the map turned the wrong way too."""
    case = "ref_const300_courtyard_ortho"
    truth = json.loads((DATA / case / "truth.json").read_text())
    fit = json.loads(run_fit(case, truth, fits).read_text())
    work = out / "work" / ("rotation" if fmt == "blender" else f"rotation_{fmt}")
    work.mkdir(parents=True, exist_ok=True)
    p, c = fit["params"], fit["disc"]
    env, bg = DATA / truth["envmap"], DATA / case / "background.png"
    if fmt == "openpbr":
        from bubblefit.io.images import write_image

        bg = work / "black.png"
        write_image(bg, np.zeros((truth["camera"]["height"], truth["camera"]["width"], 3)))
    (work / "scene.toml").write_text(
        f'[camera]\ntype = "orthographic"\nwidth = 160\nheight = 160\ndisc = [{c["cx"]}, {c["cy"]}, {c["r"]}]\n'
        f'[bubble]\nn_film = {p["n_film"]}\nroughness = {p["roughness"]}\nr_d = 0.0\nthickness_nm = {p["thickness_nm"]}\n'
        f'[lighting]\nenvmap = "{env}"\nrotation_deg = {rotation}\nscale = {p["exposure"]}\nbackground = "{bg}"\n'
        '[effects]\nmodel = "physical"\n')
    subprocess.run([sys.executable, "-m", "bubblefit", "render", str(work / "scene.toml"), "-o",
                    str(work / "bubblefit.exr")], check=True, cwd=REPO, capture_output=True)
    from bubblefit.export import export_bubble, load_fit

    renders = {}
    for name, turn in (("right", rotation), ("wrong_sign", -rotation)) if fmt == "openpbr" else (("right", rotation),):
        fit["params"]["rotation_deg"] = turn
        fit["inputs"] = {"envmap": str(env), "background": str(bg), "scene": None, "calibration": None}
        (work / f"fit_{name}.json").write_text(json.dumps(fit))
        exp = export_bubble(load_fit(work / f"fit_{name}.json"), fmt, work / f"{fmt}_{name}")
        img = work / f"{fmt}_{name}.exr"
        if fmt == "blender":
            cmd = [str(RENDER_PY), str(exp.main), "--render", str(img), "--samples", str(spp), "--threads", "2"]
        else:
            cmd = openpbr_command(exp.main.parent, img, spp)
        subprocess.run(cmd, check=True, cwd=exp.main.parent, capture_output=True,
                       env=openpbr_env() if fmt == "openpbr" else None)
        renders[name] = read(img)
    ref = read(work / "bubblefit.exr")
    inner, _ = masks(truth, ref.shape)
    row = {"check": f"map rotation and camera: bubblefit render vs the {fmt} export", "rotation_deg": rotation,
           "spp": spp, "dE00_median_inner": float(np.median(delta_e(ref, renders["right"])[inner]))}
    if "wrong_sign" in renders:
        row["backplate"] = "black (reflections only)"
        row["renderer"] = openpbr_renderer()
        row["dE00_median_inner_wrong_sign"] = float(np.median(delta_e(ref, renders["wrong_sign"])[inner]))
    save_strip(work / f"bubblefit_vs_{fmt}.png", ref, renders["right"])
    name = "rotation_check.json" if fmt == "blender" else f"rotation_check_{fmt}.json"
    (out / name).write_text(json.dumps(row, indent=1))
    print(row, flush=True)
    return row


def clean_check(out: Path, fits: Path, cases, formats=("blender", "gltf", "mitsuba", "openpbr")) -> dict:
    """The reference-renderer cases without their noise: each case's photo rendered again by
    experiments/validation/reference_renderer.py without noise or quantisation (times its
    exposure), and every render in work/<case>/ (the latest run's) and the fit's own render
    scored against it: the fidelity to the scene, free of the photo's noise floor."""
    sys.path.insert(0, str(DATA.parent))
    import make_reference as mref
    import reference_renderer as rr

    rows = {}
    for case in cases:
        if not case.startswith("ref_"):
            continue
        truth = json.loads((DATA / case / "truth.json").read_text())
        spec = mref.CASES[case]
        work = out / "work" / case
        clean_path = work / "photo_clean.exr"
        if not clean_path.exists():
            img, _ = rr.render(spec["camera"], rr.Bubble(thickness=spec["thickness"]), mref.load_env(spec["envmap"]),
                               rr.spectral_setup(truth["illuminant"], 2.0), background=spec["background"])
            from bubblefit.io.images import write_image

            write_image(clean_path, (img[..., :3] * truth["exposure"]).astype(np.float32), bit_depth=32)
        clean = read(clean_path)
        inner, _ = masks(truth, clean.shape)
        fit = json.loads(run_fit(case, truth, fits).read_text())
        row = {"fit_render": float(np.median(delta_e(clean, read(fit["outputs"]["render"]))[inner])),
               "photo": float(np.median(delta_e(clean, read(DATA / case / "photo.png"))[inner]))}
        for fmt in formats:
            for name in (fmt, f"{fmt}_conserving") if fmt == "openpbr" else (fmt,):
                if (work / f"{name}.exr").exists():
                    row[name] = float(np.median(delta_e(clean, read(work / f"{name}.exr"))[inner]))
        rows[case] = row
        print(case, row, flush=True)
    res = {"metric": "median CIEDE2000 over the inner disc against the photo rendered again without noise",
           "cases": rows}
    tag = "" if len(formats) == 4 else "_" + "-".join(formats)
    (out / f"clean_check{tag}.json").write_text(json.dumps(res, indent=1))
    return res


def save_strip(path: Path, photo: np.ndarray, render: np.ndarray) -> None:
    from bubblefit.io.images import write_image

    write_image(path, np.clip(np.concatenate([photo, render], axis=1), 0, 1))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="*", default=CASES)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--formats", nargs="*", default=["blender", "gltf", "mitsuba", "openpbr"])
    ap.add_argument("--fits", default=None, help="folder of fit results to reuse (default: OUT/fits)")
    ap.add_argument("--out", default=str(REPO / "experiments" / "results" / "export"))
    ap.add_argument("--rotation-check", action="store_true", help="only the map-rotation check (rotation_check.json)")
    ap.add_argument("--clean", action="store_true",
                    help="only score the renders already in work/ against the noise-free reference photos")
    a = ap.parse_args()
    out = Path(a.out)
    fits = Path(a.fits) if a.fits else out / "fits"
    fits.mkdir(parents=True, exist_ok=True)
    if a.rotation_check:
        for fmt in [f for f in a.formats if f in ("blender", "openpbr")]:
            rotation_check(out, fits, a.spp, fmt=fmt)
        return 0
    if a.clean:
        clean_check(out, fits, a.cases, a.formats)
        return 0
    rows = []
    for case in a.cases:
        row = check_case(case, out, fits, a.spp, a.formats)
        tag = "" if a.spp == 64 and len(a.formats) == 4 else f"_{'-'.join(a.formats)}_{a.spp}spp"
        (out / f"{case}{tag}.json").write_text(json.dumps(row, indent=1))
        rows.append(row)
    # the summary covers every case scored with these settings, in this run or an earlier one
    tag = "" if a.spp == 64 and len(a.formats) == 4 else f"_{'-'.join(a.formats)}_{a.spp}spp"
    done = {r["case"] for r in rows}
    rows += [json.loads((out / f"{c}{tag}.json").read_text()) for c in CASES
             if c not in done and (out / f"{c}{tag}.json").exists()]
    summary = {"metric": "median CIEDE2000 over the inner disc (0.8 r), photo vs render, linear sRGB clipped to "
                         "[0, 1], D65", "spp": a.spp,
               "cases": {r["case"]: {"fit_render": r["yardstick_fit_render_dE00_median"],
                                     "noise_floor_outside": r["noise_floor_photo_vs_background_dE00_median_outside"],
                                     **{f: e.get("dE00_median_inner") for f, e in r["formats"].items()},
                                     **{f + "_vs_fit_render": e.get("dE00_median_inner_vs_fit_render")
                                        for f, e in r["formats"].items() if e.get("rendered")}}
                         for r in rows}}
    (out / f"summary{tag}.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
