"""Render what `bubblefit export --to openpbr` wrote with MaterialX's own GLSL renderer.

MaterialX's GlslRenderer (the renderer behind its reference viewer, in the PyPI wheel as
``MaterialX.PyMaterialXRenderGlsl``) needs an OpenGL context: run this under a virtual
screen with software GL, e.g. ``xvfb-run -a python experiments/openpbr_glsl_render.py
EXPORT_DIR OUT.exr`` (Mesa llvmpipe).

What it does with the export folder:

* generates GLSL for the document's material (``bubble.mtlx``, OpenPBR Surface) with
  MaterialX's GLSL generator, specular environment by filtered importance sampling
  (``SPECULAR_ENVIRONMENT_FIS``, ``--samples`` per pixel and lobe);
* loads ``sphere.obj`` and places it at ``export.json``'s centre and radius, and sets the
  camera of ``export.json`` (orthographic or pinhole; pixel centres as the fit's rays);
* lights it by the environment map of ``export.json`` times the fit's gain, turned by the
  fit's rotation about +y, as the renderer's image-based light (``LightHandler``);
* renders, and composites the backplate. MaterialX's GLSL shows through a transmissive
  surface the *environment map* in the refracted direction (``mx_surface_transmission``:
  "glossy environment map refraction, ignoring any scene geometry"); the photo shows the
  background photo there. The renderer's image is split, by linearity in the light, into
  its reflection (the same program with ``transmission_weight`` and ``base_weight`` set
  to 0, so the film's layer above is unchanged and the base below it black) and its
  transmittance (a white map's full render minus its reflection render). Both walls are
  drawn (a rasteriser keeps the nearest surface: the near wall is the whole mesh, the far
  wall the triangles facing away from the camera), and the composite is
  ``R_near + T_near (R_far + T_far B)`` on the bubble, the backplate ``B`` off it.
  An orthographic camera is put 1e4 radii back (the GLSL's view direction points at the
  camera's position).
  Its own image, with the map seen through the bubble, is written beside (``*_envthrough``),
  and a diagnostic (``*_conserving``): each wall transmitting ``1 -`` its reflectance.

The wheel's ``StbImageLoader`` reads the 16-bit ``thickness.png`` as 8 bits: the film's
thickness moves in steps of 1/255 of its range here.

Writes OUT (linear RGB, EXR) and, with ``--parts``, each wall's reflection and transmittance.

References
----------
MaterialX 1.39 (Academy Software Foundation): GLSL shader generation and
``MaterialXRenderGlsl``; ``libraries/pbrlib/genglsl/lib/mx_environment_fis.glsl`` and
``mx_microfacet_specular.glsl`` (environment lookup: ``u = atan2(x, -z)/(2 pi) + 1/2``,
``v = acos(y)/pi``, after ``u_envMatrix``, whose default is a half turn about +y).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


def _mx():
    import MaterialX as mx
    from MaterialX import PyMaterialXGenGlsl as gg
    from MaterialX import PyMaterialXGenShader as gs
    from MaterialX import PyMaterialXRender as mr
    from MaterialX import PyMaterialXRenderGlsl as rg

    return mx, gs, gg, mr, rg


def to_image(arr: np.ndarray):
    """A float RGB MaterialX image from an (H, W, 3) array, row 0 first (the zenith of a map)."""
    mx, _, _, mr, _ = _mx()
    h, w = arr.shape[:2]
    img = mr.createUniformImage(w, h, 3, mr.BaseType.FLOAT, mx.Color4(0.0, 0.0, 0.0, 1.0))
    for i in range(h):
        for j in range(w):
            r, g, b = (float(v) for v in arr[i, j, :3])
            img.setTexelColor(j, i, mx.Color4(r, g, b, 1.0))
    return img


def from_image(img) -> np.ndarray:
    """(H, W, 4) float array of a captured MaterialX image, rows as stored."""
    h, w = img.getHeight(), img.getWidth()
    out = np.empty((h, w, 4), np.float32)
    for i in range(h):
        for j in range(w):
            c = img.getTexelColor(j, i)
            out[i, j] = (c[0], c[1], c[2], c[3])
    return out


def camera_matrices(rec: dict):
    """(view, projection, world) MaterialX matrices for ``export.json``'s camera and sphere."""
    mx, _, _, mr, _ = _mx()
    cam = rec["camera"]
    w, h = cam["width"], cam["height"]
    origin = np.asarray(cam["origin"], float)
    if cam["kind"] == "orthographic":
        # MaterialX's GLSL takes the view direction towards the camera's position (a pinhole's
        # V); an orthographic camera is its limit: the eye is put 1e4 radii back along its axis
        axis = origin - np.asarray(cam["target"], float)
        origin = np.asarray(cam["target"], float) + axis / np.linalg.norm(axis) * 1e4 * rec["radius"]
    eye = mx.Vector3(*map(float, origin))
    target, up = (mx.Vector3(*map(float, cam[k])) for k in ("target", "up"))
    view = mr.Camera.createViewMatrix(eye, target, up)
    dist = math.dist(origin, cam["target"])
    near, far = 0.01 * dist, dist + 100.0 * rec["radius"]
    if cam["kind"] == "orthographic":
        hw = cam["view_width"] / 2
        proj = mr.Camera.createOrthographicMatrix(-hw, hw, -hw * h / w, hw * h / w, near, far)
    else:
        hw = near * math.tan(math.radians(cam["fov_deg"]) / 2)
        proj = mr.Camera.createPerspectiveMatrix(-hw, hw, -hw * h / w, hw * h / w, near, far)
    r, c = float(rec["radius"]), rec["center"]
    world = mx.Matrix44.createScale(mx.Vector3(r, r, r)) * mx.Matrix44.createTranslation(mx.Vector3(*map(float, c)))
    return view, proj, world


class BubbleRenderer:
    """One GL context, the export's material compiled once; ``render(env, **uniforms)``."""

    def __init__(self, folder: Path, samples: int):
        mx, gs, gg, mr, rg = _mx()
        self.mx, self.mr = mx, mr
        rec = json.loads((folder / "export.json").read_text())
        self.rec = rec
        doc = mx.createDocument()
        mx.readFromXmlFile(doc, str(folder / "bubble.mtlx"))
        lib = mx.createDocument()
        search = mx.getDefaultDataSearchPath()
        mx.loadLibraries(mx.getDefaultDataLibraryFolders(), search, lib)
        doc.setDataLibrary(lib)
        ok, msg = doc.validate()
        if not ok:
            raise RuntimeError(f"bubble.mtlx does not validate: {msg}")
        gen = gg.GlslShaderGenerator.create()
        ctx = gs.GenContext(gen)
        ctx.registerSourceCodeSearchPath(search)
        opts = ctx.getOptions()
        # the options of MaterialX's viewer: GL holds an image's top row at t = 0, so file
        # textures are sampled at (u, 1 - v) for MaterialX's lower-left origin
        opts.hwSpecularEnvironmentMethod = gs.HwSpecularEnvironmentMethod.SPECULAR_ENVIRONMENT_FIS
        opts.fileTextureVerticalFlip = True
        opts.hwTransparency = True
        opts.targetColorSpaceOverride = "lin_rec709"
        elem = gs.findRenderableElements(doc)[0]
        self.shader = gen.generate("bubble", elem, ctx)
        self.pixel_source = self.shader.getSourceCode(gs.PIXEL_STAGE)
        cam = rec["camera"]
        self.size = (cam["width"], cam["height"])
        self.r = rg.GlslRenderer.create(cam["width"], cam["height"], mr.BaseType.FLOAT)
        self.r.initialize()
        th = rg.GLTextureHandler.create(mr.StbImageLoader.create())
        th.setSearchPath(mx.FileSearchPath(str(folder)))
        self.r.setImageHandler(th)
        self.gh = self.r.getGeometryHandler()
        self.gh.addLoader(mr.TinyObjLoader.create())
        self.mesh(folder / "sphere.obj")
        camera = self.r.getCamera()
        view, proj, world = camera_matrices(rec)
        camera.setViewMatrix(view)
        camera.setProjectionMatrix(proj)
        camera.setWorldMatrix(world)
        self.samples = samples
        self.shader_node = doc.getNodes("open_pbr_surface")[0].getName()  # uniforms are named after it

    def mesh(self, path: Path) -> None:
        """Render ``path`` (OBJ, texture coordinates as written) from now on."""
        self.gh.clearGeometry()
        self.gh.loadGeometry(self.mx.FilePath(str(path)), False)

    def light(self, env: np.ndarray, rotation_deg: float):
        """The renderer's image-based light: ``env`` (already times the gain) as radiance and
        irradiance map, turned about +y by ``rotation_deg`` (``setLightTransform``)."""
        mx, mr = self.mx, self.mr
        lh = mr.LightHandler.create()
        img = to_image(env)
        lh.setEnvRadianceMap(img)
        lh.setEnvIrradianceMap(img)
        lh.setEnvSampleCount(self.samples)
        lh.setLightTransform(mx.Matrix44.createRotationY(math.radians(rotation_deg)))
        self.r.setLightHandler(lh)

    def render(self, **uniforms) -> np.ndarray:
        """(H, W, 4) linear RGBA, row 0 at the top; ``uniforms`` override the material's inputs."""
        self.r.createProgram(self.shader)
        self.r.validateInputs()
        for name, value in uniforms.items():
            self.r.updateUniform(f"{self.shader_node}_{name}", self.mx.Value.createValueFromStrings(f"{value:g}", "float"))
        self.r.render()
        w, h = self.size
        img = self.mr.createUniformImage(w, h, 4, self.mr.BaseType.FLOAT, self.mx.Color4(0.0, 0.0, 0.0, 0.0))
        return from_image(self.r.captureImage(img))[::-1]


def sphere_mask(rec: dict) -> np.ndarray:
    """Pixels whose centre ray hits the sphere of ``export.json`` (closed-form ray-sphere test)."""
    cam = rec["camera"]
    w, h = cam["width"], cam["height"]
    o = np.asarray(cam["origin"], float)
    fwd = np.asarray(cam["target"], float) - o
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(cam["up"], float))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x, y = jj - w / 2, h / 2 - ii
    c, rad = np.asarray(rec["center"], float), float(rec["radius"])
    if cam["kind"] == "orthographic":
        s = cam["view_width"] / w
        orig = o + (x * s)[..., None] * right + (y * s)[..., None] * up
        d = np.broadcast_to(fwd, orig.shape)
    else:
        f = w / (2 * math.tan(math.radians(cam["fov_deg"]) / 2))
        d = fwd + (x / f)[..., None] * right + (y / f)[..., None] * up
        d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        orig = np.broadcast_to(o, d.shape)
    oc = orig - c
    b = np.sum(oc * d, -1)
    disc = b * b - (np.sum(oc * oc, -1) - rad * rad)
    return disc > 0


def far_wall_obj(src: Path, rec: dict, dst: Path) -> Path:
    """The triangles of the OBJ ``src`` whose outward normal faces away from the camera of
    ``export.json`` (``rec``): the far wall of the bubble, the second layer that a
    rasteriser's depth test hides behind the near wall (depth peeling, done on the mesh)."""
    lines = src.read_text().splitlines()
    pos = np.array([[float(t) for t in ln.split()[1:4]] for ln in lines if ln.startswith("v ")])
    c, rad = np.asarray(rec["center"], float), float(rec["radius"])
    cam = rec["camera"]
    eye = np.asarray(cam["origin"], float)
    fwd = np.asarray(cam["target"], float) - eye
    keep = []
    for ln in lines:
        if not ln.startswith("f "):
            keep.append(ln)
            continue
        idx = [int(t.split("/")[0]) - 1 for t in ln.split()[1:]]
        p = pos[idx].mean(0)
        normal = p / np.linalg.norm(p)  # the unit sphere's outward normal at the facet
        view = fwd if cam["kind"] == "orthographic" else c + rad * p - eye
        if float(normal @ view) > 0.0:
            keep.append(ln)
    dst.write_text("\n".join(keep) + "\n")
    return dst


def render_layer(br: BubbleRenderer, env: np.ndarray, rotation_deg: float) -> tuple[np.ndarray, ...]:
    """(reflection, transmittance, the renderer's own image, its reflectance) of the mesh
    ``br`` draws now (the reflectance: the reflection of a white map).

    The reflection is the program with ``transmission_weight`` and ``base_weight`` set to 0
    (the film's layer above is unchanged, the base under it black); the transmittance is the
    full render minus the reflection render, both lit by a white map (the renderer's image is
    linear in its light, and its transmission samples the map)."""
    br.light(env, rotation_deg)
    own = br.render()[..., :3]
    refl = br.render(transmission_weight=0.0, base_weight=0.0)[..., :3]
    br.light(np.ones((8, 16, 3)), 0.0)
    white_refl = br.render(transmission_weight=0.0, base_weight=0.0)[..., :3]
    trans = br.render()[..., :3] - white_refl
    return refl, trans, own, white_refl


def render_export(folder: Path, out: Path, samples: int = 64, envmap: str | None = None,
                  parts: bool = False) -> dict:
    """Render the export in ``folder`` and write ``out`` (and ``*_envthrough``); return a log.

    The composite is ``R_near + T_near (R_far + T_far B)`` on the bubble and ``B`` off it:
    the near wall (the depth test's first layer), the far wall (:func:`far_wall_obj`) seen
    through it, and the backplate ``B`` seen through both. ``*_envthrough`` is the
    renderer's own image of the near wall, the map seen through it."""
    import tempfile

    from bubblefit.io.images import read_image, write_image

    rec = json.loads((folder / "export.json").read_text())
    env = read_image(envmap or rec["envmap"]).pixels[..., :3] * float(rec["exposure"])
    rot = float(rec["rotation_deg"])
    br = BubbleRenderer(folder, samples)
    r_near, t_near, own, a_near = render_layer(br, env, rot)
    with tempfile.TemporaryDirectory() as tmp:
        br.mesh(far_wall_obj(folder / "sphere.obj", rec, Path(tmp) / "far_wall.obj"))
        r_far, t_far, _, a_far = render_layer(br, env, rot)
    mask = sphere_mask(rec)[..., None]
    w, h = br.size
    back = read_image(rec["background"]).pixels[..., :3] if rec.get("background") else np.zeros((h, w, 3))
    comp = np.where(mask, r_near + t_near * (r_far + t_far * back), back).astype(np.float32)
    write_image(out, comp, bit_depth=32)
    write_image(out.with_name(out.stem + "_envthrough" + out.suffix), np.where(mask, own, back).astype(np.float32),
                bit_depth=32)
    # a diagnostic, not the renderer's image: each wall transmitting what its film does not
    # reflect (1 - its reflectance of a white map), as energy conservation would have it
    conserving = r_near + (1 - a_near) * (r_far + (1 - a_far) * back)
    write_image(out.with_name(out.stem + "_conserving" + out.suffix),
                np.where(mask, conserving, back).astype(np.float32), bit_depth=32)
    if parts:
        for name, img in (("near_reflection", r_near), ("near_transmittance", t_near), ("far_reflection", r_far),
                          ("far_transmittance", t_far)):
            write_image(out.with_name(f"{out.stem}_{name}{out.suffix}"), img.astype(np.float32), bit_depth=32)
    on = mask[..., 0]
    return {"samples": samples, "size": [w, h], "pixels_on_bubble": int(on.sum()),
            "near_transmittance_mean": [float(v) for v in t_near[on].mean(0)],
            "far_transmittance_mean": [float(v) for v in t_far[on].mean(0)],
            "far_reflection_mean": [float(v) for v in r_far[on].mean(0)],
            "near_reflectance_mean": [float(v) for v in a_near[on].mean(0)]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folder", help="the folder `bubblefit export --to openpbr` wrote")
    ap.add_argument("out", help="the composite, linear EXR")
    ap.add_argument("--samples", type=int, default=64, help="environment samples per pixel and lobe (FIS)")
    ap.add_argument("--envmap", default=None, help="replace export.json's environment map")
    ap.add_argument("--parts", action="store_true", help="also write the reflection and transmittance images")
    a = ap.parse_args()
    info = render_export(Path(a.folder), Path(a.out), a.samples, a.envmap, a.parts)
    print(json.dumps(info))
    return 0


if __name__ == "__main__":
    sys.exit(main())
