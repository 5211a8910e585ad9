"""A validation photo against bubblefit's render at the case's true parameters: how much of a
fit's floor the forward model leaves before anything is fitted.

Renders the case (physical model, exact Airy film at 100 wavelengths, 8 internal bounces,
the background photo, the true exposure, thickness and disc, a mirror film) with one ray
per pixel, with the pixel footprint (RenderConfig.pixel_footprint) and with 16 rays per
pixel, and prints for each the reduced chi^2 with the 3 % floor and the outliers over the
pixels a fit uses (inside 0.96 of the radius, no clipped channel nearby), with the fit's
noise model, and how that chi^2 splits by radius and between the glint's pixels and the
rest. Channels the photo clipped at black are censored as a fit censors them
(``censored_residual``: a film's colour outside the sRGB gamut is a negative channel).
Run from the repository root (FILT=mipmap for the lobe's quadrature at roughness 0,
ONLY=point,footprint to skip variants, BLOCK=2 to score 2 x 2 block means of the photo
against a render at half the resolution, as a fit's last level does):

    PYTHONPATH=. .venv/bin/python experiments/validation/truth_misfit.py CASE
"""
import json, os, sys, dataclasses, numpy as np
from bubblefit.model.scene import Scene, read_envmap
from bubblefit.model.render import render
from bubblefit.io.images import read_image
from bubblefit.inverse import block_mean, censored_residual, noise_sigma, saturation_mask
from bubblefit.lighting.filtering import FilterConfig
D = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
case = sys.argv[1]
t = json.load(open(f"{D}/{case}/truth.json"))
K = int(os.environ.get("BLOCK", "1"))  # score k x k block means, as a fit's coarser level does
cam = dict(t["camera"]); cam.pop("fov_axis", None)
cam["width"] //= K; cam["height"] //= K
if cam["type"] == "orthographic":
    cam["disc"] = [t["disc"]["cx"] / K, t["disc"]["cy"] / K, t["disc"]["r"] / K]
th = t["thickness"]
thick = {"profile": "constant", "thickness_nm": th["thickness_nm"]} if th["profile"] == "constant" else \
        {"profile": "drainage", "top_nm": th["top_nm"], "bottom_nm": th["bottom_nm"], "exponent": th["exponent"]}
if thick["profile"] == "constant":
    bub = {"thickness_nm": th["thickness_nm"]}
else:
    bub = {"thickness": {k: v for k, v in thick.items()}}
bub.update({"roughness": 0.0, "r_d": 0.0, "r_s": 0.03, "n_film": 1.4})
bg = read_image(f"{D}/{case}/background.png").pixels
photo = read_image(f"{D}/{case}/photo.png").pixels
sigma = noise_sigma(photo, 2e-3, 2e-4, 8)
sat = saturation_mask(photo, 1.0, None)
if K > 1:
    bg, photo = block_mean(bg, K), block_mean(photo, K)
    sigma = np.sqrt(block_mean(sigma**2, K) / (K * K))
    sat = block_mean(sat.astype(float)[..., None], K)[..., 0] > 0
sc = Scene.from_dict({"camera": cam, "bubble": bub,
                      "lighting": {"envmap": f"{D}/{t['envmap']}"},
                      "effects": {"model": "physical", "interference": "airy", "filtering": os.environ.get("FILT", "mirror"), "nodes": 4, "diffuse": False,
                                  "bounces": 8, "spectral": {"method": "uniform", "samples": 100}, "front_reflection": True,
                                  "rear_reflection": True, "transmission": True}})
env = read_envmap(f"{D}/{t['envmap']}")
cfg, _ = sc.config(env, background=bg)
# the background photo (at the block level), as a fit reads it behind the bubble
cfg = dataclasses.replace(cfg, effects=dataclasses.replace(cfg.effects, background="photo"))
if os.environ.get("FILT"):  # the scene's mirror at roughness 0 would otherwise win the filter's decision
    cfg = dataclasses.replace(cfg, effects=dataclasses.replace(cfg.effects, filtering=FilterConfig(os.environ["FILT"], nodes=4)))
p = dataclasses.replace(sc.params(), exposure=np.float32(t["exposure"]))
h, w = photo.shape[:2]
disc = t["disc"]
jj, ii = np.meshgrid((np.arange(w) + 0.5) * K, (np.arange(h) + 0.5) * K)
rho = np.hypot(jj - disc["cx"], ii - disc["cy"]) / disc["r"]
used = (rho < 0.96) & ~sat
variants = [("point", dict(pixel_footprint=False)), ("footprint", dict(pixel_footprint=True)),
            ("16 rays", dict(pixel_footprint=False, samples_per_pixel=16))]
if os.environ.get("ONLY"):
    variants = [v for v in variants if v[0] in os.environ["ONLY"].split(",")]
print(case, "filter", os.environ.get("FILT", "mirror"), "block", K)
for name, kw in variants:
    img = np.asarray(render(p, dataclasses.replace(cfg, **kw), env, bg))
    chi = np.sum(censored_residual(photo, img, xp=np) ** 2 / (sigma**2 + (0.03 * np.clip(photo, 0, None)) ** 2), axis=-1)
    print(case, name, "chi2 floor %.2f outliers %.1f %%" % (chi[used].sum() / (3 * used.sum()), 100 * np.mean(chi[used] > 30)),
          "clipped left out", int((sat & (rho < 0.96)).sum()), flush=True)
    bins = [0, 0.5, 0.7, 0.85, 0.96]
    bright = np.max(img, axis=-1) > 5 * np.median(np.max(photo, axis=-1)[rho < 0.96])
    from scipy import ndimage as ndi
    gl = ndi.binary_dilation(bright | sat, iterations=2) & used
    print("   share of chi2 by radius:", " ".join("%.2f-%.2f: %.0f%%" % (a, b, 100 * chi[used & (rho >= a) & (rho < b)].sum() / chi[used].sum()) for a, b in zip(bins[:-1], bins[1:])),
          "| glint pixels %d carry %.0f%%" % (gl.sum(), 100 * chi[gl].sum() / chi[used].sum()),
          "| chi2 floor without glint %.2f, without rho>0.85 %.2f" % (chi[used & ~gl].sum() / (3 * (used & ~gl).sum()), chi[used & (rho < 0.85)].sum() / (3 * (used & (rho < 0.85)).sum())), flush=True)
