"""The fit's compiled programs, prepared, stored and loaded in one place.

The fit's algorithm (:mod:`.fit`, :mod:`._local`, :mod:`.search`, :mod:`._maps`,
:mod:`._uncertainty`) asks for programs by what they compute; this module builds them
(:func:`solver`, :func:`reporter`, the renders of a level), keeps them in the executable
store (:func:`bubblefit.io.executables.stored`; the model's own programs come from
:mod:`bubblefit.model.programs`) and starts their compiles ahead (:func:`warm_up`).

Compiled programs see a level padded (:func:`padded`): its rows and columns rounded up to
a few sizes, its camera replaced by the padded size's canonical one and the disc passed
as data, so that one program serves every photo whose level pads to that size, wherever
the bubble lies in it (a user's next photo does not compile again); a solve renders the
level's fitted pixels alone, listed in the padded image (:func:`fitted_pixels`). Compiled
solvers are cached per static configuration (effects, parameter table, padded size), so
photos of any framing whose levels pad to the same size share the compiled solves and the
persistent cache's programs.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage as ndi

from ._censored import censored_residual
from ._lm import JACOBIANS, MAX_REJECTIONS, robust
from ._observation import Level
from ._options import FitOptions, SolverSettings
from ._parameters import ParameterTable
from ..io.executables import deferred, stored
from ..io.jaxcache import ynn_fusions_off_option
from ..model.geometry import OrthographicCamera, canonical_frame, compose_shift, gauss_offsets, pixel_offsets
from ..model.programs import prepare_loaded, render_loaded
from ..model.render import RenderConfig, render_pixels

__all__ = ["solver", "stored_solver", "batched_solver", "reporter", "held_values", "solve_program",
           "prepare_local", "prepare_reporter", "render_level", "prepare_render_level", "render_bubble",
           "prepare_render_bubble", "final_params", "SolveSettings", "FINAL_SOLVE", "SEARCH_SOLVE", "WARM_SOLVE",
           "FINAL_JACOBIAN", "FINAL_COMPILE", "SEARCH_COMPILE", "warm_up", "Padded", "padded", "unpadded",
           "padded_size", "Pixels", "fitted_pixels", "pixel_bucket", "bubble_list", "SolvePixels", "solve_pixels",
           "block_means", "rim_blocks", "RIM_SAMPLES", "RIM_BAND", "RIM_RULE"]


# ---------------------------------------------------------------------------------------
# A level as compiled programs see it
# ---------------------------------------------------------------------------------------

#: The finest step of the padded sizes (:func:`padded_size`).
BUCKET = 16


def padded_size(n: int) -> int:
    """``n`` rounded up to a multiple of ``max(BUCKET, 2^(bits(n) - 4))``: steps of 16 up to
    255 pixels, then an eighth to a sixteenth of the size (at most 12.5 % padding), so a
    few programs serve every photo size."""
    step = max(BUCKET, 1 << max(0, int(n).bit_length() - 4))
    return -(-int(n) // step) * step


@dataclass
class Padded:
    """A level padded at its bottom and right (:func:`padded`): the canonical
    configuration, the photo, weights and background (jnp, float32; weight 0 in the
    padding), and ``base``, the shift that moves the canonical disc onto the level's."""

    cfg: RenderConfig
    y: jnp.ndarray
    w: jnp.ndarray
    bg: jnp.ndarray | None
    base: np.ndarray
    #: the background photo's noise standard deviation, padded like ``bg`` (None without one)
    bg_sigma: jnp.ndarray | None = None


def padded(lev: Level) -> Padded:
    """``lev`` as compiled programs see it. An orthographic level is padded to
    :func:`padded_size` rows and columns and takes the canonical camera of that size
    (:func:`~bubblefit.model.geometry.canonical_frame`); a perspective one, whose rays
    depend on its size, is passed as it is (``base`` the identity)."""
    f32 = lambda a: None if a is None else jnp.asarray(a, jnp.float32)
    if not isinstance(lev.cfg.camera, OrthographicCamera):
        return Padded(lev.cfg, f32(lev.y), f32(lev.w), f32(lev.bg), np.asarray([0.0, 0.0, 1.0], np.float32),
                      f32(lev.bg_sigma))
    h, w = lev.y.shape[:2]
    hb, wb = padded_size(h), padded_size(w)
    camera, base = canonical_frame(lev.cfg.camera, hb, wb)
    pad = lambda a: None if a is None else f32(np.pad(a, ((0, hb - h), (0, wb - w), (0, 0))))
    return Padded(replace(lev.cfg, camera=camera), pad(lev.y), pad(lev.w), pad(lev.bg), base, pad(lev.bg_sigma))


def unpadded(lev: Level, a) -> np.ndarray:
    """``a``, an image ``(hb, wb, ...)`` of :func:`padded`'s level, on ``lev``'s own pixels
    (numpy, ``(h, w, ...)``): the padding at the bottom and right dropped."""
    h, w = lev.y.shape[:2]
    return np.asarray(a)[:h, :w]


@dataclass
class Pixels:
    """The fitted pixels of a padded level (:func:`fitted_pixels`): ``rows``, ``cols``,
    ``idx`` (steps, chunk) in the padded image, as :func:`~bubblefit.model.render.render_pixels`
    reads them, the photo ``y`` and weights ``w`` (steps chunk, 3) there (weight 0 on the
    entries that pad the list), and ``flat``, the pixels' flat indices in the level."""

    padded: Padded
    rows: jnp.ndarray
    cols: jnp.ndarray
    idx: jnp.ndarray
    y: jnp.ndarray
    w: jnp.ndarray
    flat: np.ndarray

    def scatter(self, lev: Level, a) -> np.ndarray:
        """``a`` (numpy), a flat residual ``(steps chunk 3, ...)`` over this list, as the
        flat residual ``(h w 3, ...)`` of ``lev`` (0 at the pixels not fitted)."""
        a = np.asarray(a)
        h, w = lev.y.shape[:2]
        out = np.zeros((h * w, 3, *a.shape[1:]), a.dtype)
        out[self.flat] = a.reshape(-1, 3, *a.shape[1:])[: self.flat.size]
        return out.reshape(h * w * 3, *a.shape[1:])


#: Lengths of a fitted-pixel list per octave (:func:`pixel_bucket`): a thickness map's
#: chunks (:func:`_even_chunks`).
BUCKETS_PER_OCTAVE = 4
#: Lengths per octave of the lists that a local solve and the final render draw in one
#: program (:func:`fitted_pixels`' ``"bucket"`` layout, :func:`solve_pixels`): a solve
#: renders its list at every trial point and pushes it through the Jacobian's tangents at
#: every accepted one, so its padding is paid many times over. Eight lengths an octave
#: pad at most an eighth of the list: the 1554 fitted pixels of the 320x320 constant
#: photo's fit level (docs/speed.md) are drawn as 1664 instead of 1792, its final render's
#: 28,851 as 30,720 instead of 32,768.
SOLVE_BUCKETS_PER_OCTAVE = 8


def pixel_bucket(n: int, per_octave: int = BUCKETS_PER_OCTAVE) -> int:
    """The length a list of ``n`` fitted pixels is padded to: the next of ``per_octave``
    lengths per octave, ``2^k (1 + j / per_octave)`` (at least 64). A disc a few percent
    larger or smaller mostly shares its programs, and the padding costs at most
    ``1 / per_octave`` of the list (a power of two cost up to all of it: 2104 pixels
    rendered as 4096)."""
    n = max(int(n), 64)
    top = 1 << (n - 1).bit_length()
    step = max(1, (top // 2) // per_octave)
    return min(top, -(-n // step) * step)


def _chunked(count: int, n: int, chunk: int) -> tuple[int, int, np.ndarray]:
    """``(steps, size, take)``: a list of ``count`` entries padded to ``n`` (at least
    ``count``) and split into ``steps`` equal chunks of ``size <= chunk`` (the list stays
    about ``n`` long); ``take`` (steps size,) indexes the entries, the padding repeating
    the last one."""
    steps = -(-n // chunk)
    size = -(-n // steps)
    return steps, size, np.minimum(np.arange(steps * size), max(count - 1, 0))


def _even_chunks(count: int, chunk: int) -> tuple[int, int]:
    """``(steps, size)``: the fewest chunks of at most ``chunk`` (a power of two) that hold
    ``count`` entries, each :func:`pixel_bucket` of its share ``ceil(count / steps)``. The
    padding costs at most a quarter of a chunk's share (the coarse level of a 96 px
    sequence's map, 1030 pixels: 3 chunks of 384, 1152 in all, where whole chunks of 512
    render 1536), and a level's programs serve every count with the same number of chunks
    and the same bucket of a share (four lengths of a chunk per octave)."""
    steps = max(1, -(-int(count) // chunk))
    return steps, min(chunk, pixel_bucket(-(-int(count) // steps)))


def fitted_pixels(lev: Level, chunk: int, mask: np.ndarray | None = None, *,
                  layout: Literal["bucket", "whole", "even"] = "bucket") -> Pixels:
    """The pixels of ``lev`` a fit compares (its mask, or ``mask``), listed in the padded level
    (:func:`padded`), the list padded by repeating its last pixel with weight 0 and split into
    chunks of at most ``chunk``. The padded count (``layout``): ``"bucket"``, the pixels'
    count rounded up to :func:`pixel_bucket` with :data:`SOLVE_BUCKETS_PER_OCTAVE`; ``"whole"``, a multiple of ``chunk`` (a program
    per chunk serves every count); ``"even"``, the fewest chunks of at most ``chunk``, each of
    the length :func:`pixel_bucket` gives its share of the pixels (:func:`_even_chunks`).
    A solve renders these alone: on a disc that fills 55 % of its level, about half the
    pixels of the padded image."""
    pad = padded(lev)
    w, wb = lev.y.shape[1], pad.cfg.shape[1]
    flat = np.flatnonzero((lev.mask if mask is None else mask).reshape(-1))
    if layout == "even":
        steps, chunk = _even_chunks(flat.size, chunk)
        n = steps * chunk
    elif layout == "whole":
        n = max(1, -(-flat.size // chunk)) * chunk
    elif layout == "bucket":
        n = pixel_bucket(flat.size, SOLVE_BUCKETS_PER_OCTAVE)
    else:
        raise ValueError(f"unknown pixel layout {layout!r}")
    steps, size, take = _chunked(flat.size, n, chunk)
    rows, cols = np.divmod(flat[take], w)
    keep = (np.arange(steps * size) < flat.size)[:, None]
    y = np.where(keep, lev.y.reshape(-1, 3)[flat[take]], 0.0)
    wt = np.where(keep, lev.w.reshape(-1, 3)[flat[take]], 0.0)
    i32 = lambda a: jnp.asarray(a.reshape(steps, size), jnp.int32)
    return Pixels(pad, i32(rows), i32(cols), i32(rows * wb + cols), jnp.asarray(y, jnp.float32),
                  jnp.asarray(wt, jnp.float32), flat)


#: Rays per block (``s x s``, placed by :data:`RIM_RULE`) that a local solve renders for
#: the blocks at the bubble's rim (:func:`solve_pixels`), where the fit reads a drainage
#: profile (its top and bottom lie at the rim and move with the disc's radius, which one
#: ray a block biases: on development case ref_drain_lin_city_ortho_offc the top +4.2 nm
#: with one ray, +1.8 nm with these; experiments/results/rim_blocks/). A constant film's
#: solve keeps one ray a block: its thickness is read over the whole film (ref_const300 and
#: ref_const620 moved by under 0.1 of their standard errors with the rim rays) and the rim's
#: rays cost about 1.45x the solve.
RIM_SAMPLES = 4
#: The rim's blocks (:func:`rim_blocks`): a fitted block whose centre lies within this many
#: blocks of the nearest block centre off the bubble.
RIM_BAND = 2.5
#: The rim blocks' quadrature (:func:`solve_pixels`): ``gauss``
#: (:func:`~bubblefit.model.geometry.gauss_offsets`: exact for a radiance cubic across the
#: block) or ``box``, the stratified centres of :func:`~bubblefit.model.geometry.pixel_offsets`.
RIM_RULE = "gauss"


def rim_blocks(lev: Level, band: float = RIM_BAND) -> np.ndarray:
    """(h, w) bool: the fitted blocks of ``lev`` at the bubble's rim, those whose centre
    lies within ``band`` blocks of the nearest block whose centre ray misses the bubble
    (the Euclidean distance transform of ``lev.inside``; a frame's edge is not a rim).

    A block of the photo is the mean of its pixels, each the light a camera's pixel
    collects over its area: the box filter of :func:`~bubblefit.model.geometry.pixel_offsets`.
    One ray at the block's centre stands for that mean where the light changes slowly
    across the block; towards the rim the incidence cosine ``cos = sqrt(1 - rho^2)``
    changes ever faster (``d cos / d rho = -rho / cos``), and with it the film's path
    ``2 n d cos(theta_t)``, its Fresnel reflectance and its drainage thickness, so the
    centre ray's value departs from the block's mean by the second-order term
    ``f'' h^2 / 24`` of a block ``h`` wide, which grows as ``1 / cos^3``. These blocks
    are chosen from the level's starting disc, so that the solve's lists keep their
    shapes (and its compiled program) while the disc is refined within a block or two.
    """
    inside = np.asarray(lev.inside, bool)
    if inside.all():  # no block off the bubble: no rim in the frame
        return np.zeros(inside.shape, bool)
    return np.asarray(lev.mask, bool) & (ndi.distance_transform_edt(inside) <= band)


@dataclass
class SolvePixels:
    """A local solve's fitted blocks and the rays it renders for them (:func:`solve_pixels`):
    ``pixels``, the blocks (:class:`Pixels`, one list as :func:`fitted_pixels` pads it),
    ``samples``, the rays of a rim block, and ``rays``, what the solve renders:
    ``(rows, cols, idx, samples, block, weight)`` (steps, chunk), every block's rays in one
    list, each at the fractional pixel coordinates of its block's quadrature, with its flat
    pixel index, its block's ray count, its block's place in ``pixels`` and its weight
    there (:func:`block_means`; the blocks that pad ``pixels`` take no ray, and the list is
    padded as :func:`fitted_pixels` pads the blocks' by rays of weight 0), or, with ``samples`` None,
    ``pixels``' own ``(rows, cols, idx)``."""

    pixels: Pixels
    samples: int | None
    rays: tuple

    @property
    def padded(self) -> Padded:
        return self.pixels.padded

    @property
    def y(self) -> jnp.ndarray:
        return self.pixels.y

    @property
    def w(self) -> jnp.ndarray:
        return self.pixels.w

    @property
    def flat(self) -> np.ndarray:
        return self.pixels.flat

    def scatter(self, lev: Level, a) -> np.ndarray:
        """:meth:`Pixels.scatter` of the blocks."""
        return self.pixels.scatter(lev, a)


def block_means(img, block, weight, blocks: int):
    """The blocks' values (``blocks``, 3) from their rays' radiance ``img`` (R, 3): each
    block the sum of its rays' radiance times their weights (``block``, ``weight`` (R,),
    :attr:`SolvePixels.rays`), the quadrature of the block's box average
    (:func:`~bubblefit.model.geometry.pixel_offsets`,
    :func:`~bubblefit.model.geometry.gauss_offsets`), a segment sum of a fixed length."""
    return jax.ops.segment_sum(img * weight[:, None], block, num_segments=blocks)


def solve_pixels(lev: Level, chunk: int, rim_samples: int = RIM_SAMPLES, band: float = RIM_BAND,
                 rule: str = RIM_RULE) -> SolvePixels:
    """The fitted pixels of ``lev`` as a local solve renders them: the blocks at the rim
    (:func:`rim_blocks` within ``band``) with ``s x s`` rays each, ``s^2 = rim_samples``,
    placed and weighted by ``rule`` (:data:`RIM_RULE`), so that their model is the mean over
    the block's area that the photo's block holds (the box filter of the camera's pixels),
    and the others with one ray at the centre; the level's own list (:func:`fitted_pixels`)
    where there is no rim, with ``rim_samples`` 0, or where the level takes several rays per
    pixel itself. All the rays form one list, its length rounded up as
    :func:`pixel_bucket` rounds the blocks' (so that the solve's program serves the disc
    while it moves within the band), of at most ``chunk`` rays a step, rendered in one pass."""
    px = fitted_pixels(lev, chunk)
    rim = rim_blocks(lev, band) if rim_samples > 1 and lev.cfg.samples_per_pixel == 1 else None
    if rim is None or not rim.any():
        return SolvePixels(px, None, (px.rows, px.cols, px.idx))
    off, wts = gauss_offsets(rim_samples) if rule == "gauss" else (
        pixel_offsets(rim_samples), np.full(rim_samples, 1.0 / rim_samples))
    r, c, i = (np.asarray(a).reshape(-1) for a in (px.rows, px.cols, px.idx))
    at_rim = np.zeros(r.size, bool)
    at_rim[: px.flat.size] = rim.reshape(-1)[px.flat]
    k = np.where(at_rim, rim_samples, 1) * (np.arange(r.size) < px.flat.size)  # no ray for the padding blocks
    block = np.repeat(np.arange(r.size), k)
    first = np.cumsum(k) - k  # each block's first ray
    j = np.arange(block.size) - first[block]  # a ray's place among its block's
    rim_ray = at_rim[block]
    rows = r[block] + np.where(rim_ray, off[j % rim_samples, 0], 0.0)
    cols = c[block] + np.where(rim_ray, off[j % rim_samples, 1], 0.0)
    weight = np.where(rim_ray, wts[j % rim_samples], 1.0)
    steps, size, take = _chunked(block.size, pixel_bucket(block.size, SOLVE_BUCKETS_PER_OCTAVE), chunk)
    pad = np.arange(steps * size) >= block.size  # rays that pad the list: weight 0
    as_list = lambda a, dt: jnp.asarray(np.asarray(a)[take].reshape(steps, size), dt)
    rays = (as_list(rows, jnp.float32), as_list(cols, jnp.float32), as_list(i[block], jnp.int32),
            as_list(k[block], jnp.float32), as_list(block, jnp.int32),
            jnp.asarray(np.where(pad, 0.0, weight[take]).reshape(steps, size), jnp.float32))
    return SolvePixels(px, int(rim_samples), rays)


# ---------------------------------------------------------------------------------------
# The programs
# ---------------------------------------------------------------------------------------

#: The final solve's Jacobian after a global search (a key of
#: :data:`~bubblefit.inverse._local.JACOBIANS`): by columns, faster per step on the fit
#: level; its program compiles in the background during the search, whose own solve
#: keeps the groups (shorter to compile, on the first fit's critical path). A warm-started
#: fit keeps the groups too: its solve compiles on the critical path, and on a sequence's
#: 64x64 frames pinned to one core the columns made 5.24 and 4.36 frames/s against 5.66
#: and 4.93 by groups (alternate runs).
FINAL_JACOBIAN = "columns"


#: XLA's compiler options (``(name, value)`` pairs) for the solves of a fit that searches
#: globally: the search's and the final one (a warm-started fit, a sequence's frame, keeps
#: XLA's defaults: there the run counts more than the compile). On an empty cache these
#: compiles are most of the first fit, so both solves are compiled at XLA's backend
#: optimisation level 1 (its default is 2) and with XLA:CPU's older per-element emitters
#: for fused loops instead of its MLIR fusion emitters (``xla_cpu_use_fusion_emitters``,
#: an option of the pinned jaxlib; a jaxlib without it refuses the compile). Compiled
#: alone, the emitters took the final solve's compile CPU from 7.6-7.9 s to 5.6-5.7 s for
#: a run from the set-up's values of 0.55-0.59 s against 0.49 s, and the search solve's
#: from 4.9-5.0 s to 3.2-3.3 s for the same run (level 1 alone had taken the final
#: solve's from 9.6-10.5 s to 7.8-7.9 s). In alternate processes
#: (``experiments/bench_fit.py --stages --empty-cache``, three rounds) the first fit took
#: 13.7-13.9 s with level 1 alone, 11.9-12.2 s with the older emitters for the search's
#: solve (and :data:`~bubblefit.model.programs.TERMS_COMPILE`), and 10.5-11.0 s with them
#: for both solves (18.4-19.2 s of CPU against 24.8-25.3 s); the warm fit 0.86-0.87 s,
#: 0.87-0.96 s and 0.89-0.91 s. Both are compiled without XLA:CPU's YNNPACK reduction
#: fusions where the jaxlib is a known one (:func:`~bubblefit.io.jaxcache.ynn_fusions_off_option`):
#: their local solve runs faster without them, while a sequence's per-pixel map programs,
#: which keep XLA's defaults, ran slower without them (docs/speed-profile.md).
FINAL_COMPILE = ((("xla_backend_optimization_level", 1), ("xla_cpu_use_fusion_emitters", False))
                 + ynn_fusions_off_option())


SEARCH_COMPILE = FINAL_COMPILE


@dataclass(frozen=True)
class SolveSettings:
    """How a local solve's program is built (:func:`solver`): its Jacobian (a key of
    :data:`~bubblefit.inverse._lm.JACOBIANS`), XLA's compiler options, and whether it stops
    on rejections and restarts (``stall``, :func:`bubblefit.inverse._local.solve_local`)."""

    jacobian: str = "groups"
    compile_options: tuple = ()
    stall: bool = True
    #: rays per block at the rim (:func:`solve_pixels`; 0: the level's rays everywhere)
    rim_samples: int = RIM_SAMPLES
    #: the rim's width in blocks (:func:`rim_blocks`)
    rim_band: float = RIM_BAND
    #: the rim rays' quadrature (:data:`RIM_RULE`)
    rim_rule: str = RIM_RULE


#: The final solve after a global search (:data:`FINAL_JACOBIAN`, :data:`FINAL_COMPILE`).
FINAL_SOLVE = SolveSettings(FINAL_JACOBIAN, FINAL_COMPILE, True)
#: The global search's own short solves (:data:`SEARCH_COMPILE`): they hold the disc and
#: only start the final solve, which renders the rim's blocks with their area's rays.
SEARCH_SOLVE = SolveSettings("groups", SEARCH_COMPILE, True, 0)
#: A warm-started fit's solve (a sequence's frame from its predecessor's values, ``auto``'s
#: physical solve from the paper model's or the search image's, a doubtful warm start's
#: second solve): the groups, XLA's defaults but for the YNNPACK fusions
#: (:func:`~bubblefit.io.jaxcache.ynn_fusions_off_option`, as :data:`FINAL_COMPILE`), and
#: the searched fit's stop on rejections and restarts
#: (:class:`~bubblefit.inverse._lm_solver.LevenbergMarquardt`), rather than optimistix' Cauchy test
#: alone, which near the optimum spends most of a solve's steps rejected
#: (:data:`~bubblefit.inverse._lm.STOP_DECREMENT`).
WARM_SOLVE = SolveSettings("groups", ynn_fusions_off_option(), True)


def final_params(table, vals: dict, opts: FitOptions):
    """The render parameters of the final full-resolution image (:func:`bubblefit.inverse.fit._finish`)."""
    return table.render_params({k: jnp.asarray(v, jnp.float32) for k, v in vals.items()},
                               "map" if opts.thickness == "map" else None)



@functools.lru_cache(maxsize=64)
def solver(cfg: RenderConfig, table: ParameterTable, robust_scale: float, max_steps: int, rtol: float, atol: float,
           max_rejections: int | None = MAX_REJECTIONS, jacobian: str = "groups", compile_options: tuple = (),
           rim: tuple | None = None):
    """Jitted ``solve(z0, args) -> (z, ok, maxed, steps, residual, J)`` and ``resid``
    (``jacobian``: a key of :data:`JACOBIANS`; ``compile_options``: XLA's compiler options
    for the solve's program as ``(name, value)`` pairs, ``()`` for XLA's defaults;
    ``rim``: ``(rays per rim block, rule)`` where the blocks at the rim take several rays,
    :func:`solve_pixels`).

    ``args = (fixed, env, background, background_sigma, photo, weights, base, (rows, cols, idx))``: the
    fitted pixels of a padded level (:func:`fitted_pixels`), each rendered with ``cfg``'s
    rays; with ``rim``, ``(rows, cols, idx, samples, block, weight)``, a solve's rays
    (:attr:`SolvePixels.rays`), rendered in one pass and summed per block with their
    weights (:func:`block_means`);
    the residual is ``robust((render - photo) * weights)`` over them, censored where the photo
    clipped a channel at black (:func:`~bubblefit.inverse._censored.censored_residual`: a film's
    colour outside the camera's gamut has a negative channel, which the photo records as 0;
    only a model above the clip leaves a residual there) (the weights widened by
    the background photo's noise, ``background_sigma``, carried by ``dI/dL_b``; Deming,
    J. Wiley 1943: the errors-in-variables weighting), flattened, rendered
    with the disc moved by ``base`` and then by the fitted refinement
    (:func:`~bubblefit.model.geometry.compose_shift`).
    """

    def resid(z, args):
        fixed, env, bg, bg_sigma, y, w, base, rays = args
        p = replace((q := table.render_params(table.values(z, fixed))), disc=compose_shift(base, q.disc))
        if rim is None:
            draw = lambda b: render_pixels(p, cfg, env, b, *rays)
        else:
            draw = lambda b: block_means(render_pixels(p, cfg, env, b, *rays[:4]), rays[4].reshape(-1),
                                         rays[5].reshape(-1), y.shape[0])
        if bg_sigma is None:
            img = draw(bg)
        else:
            # The background photo is a measurement too (errors in variables): each pixel's
            # variance is the photo's plus the background's noise carried by the model's
            # own transmission dI/dL_b at the current parameters (Deming's weighting, the
            # profile likelihood of the unknown true background), so that t is not pulled
            # low by a noisy regressor and its error bar includes the background's share.
            img, carried = jax.jvp(draw, (bg,), (bg_sigma,))
            w = w * jax.lax.rsqrt(1.0 + (w * carried) ** 2)
        return robust(-censored_residual(y, img) * w, robust_scale).reshape(-1)

    # imported here, where a solve is traced: a stored solve runs without them (:mod:`._lm_solver`)
    import optimistix as optx

    from ._lm_solver import LevenbergMarquardt

    lm = LevenbergMarquardt(rtol=rtol, atol=atol, max_rejections=max_rejections, free=table.free,
                            jacobian=JACOBIANS[jacobian](resid, table))

    @functools.partial(jax.jit, compiler_options=dict(compile_options) or None)
    def solve(z0, args):
        sol = optx.least_squares(resid, lm, z0, args, max_steps=max_steps, throw=False)
        # The last accepted point's residual and Jacobian, which the solver evaluated there
        # (every solve takes at least one step, and the first is accepted): tracing them
        # again would double the program's renders and its compile time.
        f_info = sol.state.f_info
        z, r, jac = sol.value, f_info.residual, f_info.jac.as_matrix()
        maxed = (sol.result == optx.RESULTS.max_steps_reached) | (
            sol.result == optx.RESULTS.nonlinear_max_steps_reached)
        return (z, sol.result == optx.RESULTS.successful, maxed, sol.stats["num_steps"], r, jac)

    return solve, jax.jit(resid)


@functools.lru_cache(maxsize=64)
def stored_solver(*key):
    """:func:`solver`'s ``solve`` through the executable store (:func:`bubblefit.io.executables.stored`):
    a new process loads the compiled solve instead of tracing it again."""
    return stored(deferred(lambda: solver(*key)[0]), "inverse._programs.solver", key)


@functools.lru_cache(maxsize=16)
def batched_solver(*key):
    """:func:`solver`'s ``solve`` vmapped over frames: ``z0``, ``y`` and ``w`` carry a
    leading frame axis; the fixed values, the map, the background and the disc are shared."""
    solve, _ = solver(*key)
    return jax.jit(jax.vmap(solve, in_axes=(0, (None, None, None, None, 0, 0, None, None))))


@functools.lru_cache(maxsize=64)
def reporter(table: ParameterTable):
    """Jitted ``(z, fixed) -> reported values`` and its Jacobian (for the delta method),
    through the executable store (:func:`prepare_reporter` starts their compile)."""
    def rep(z, fixed):
        return table.reported(table.values(z, fixed))

    return (stored(jax.jit(rep), "inverse._programs.reporter", table),
            stored(jax.jit(jax.jacfwd(rep)), "inverse._programs.reporter_jacobian", table))


def held_values(table: ParameterTable, vals: dict) -> dict:
    """The values of ``vals`` that ``table`` holds, as the solve's programs (batched too) and
    :func:`reporter`'s take them (float32)."""
    return {k: jnp.asarray(v, jnp.float32) for k, v in vals.items() if k not in table.free}


def solve_program(lev: Level, table: ParameterTable, solver: SolverSettings, vals: dict, env, max_steps: int | None,
                  settings: SolveSettings):
    """``(key, args, pixels)``: the key of :func:`~bubblefit.inverse._local.solve_local`'s solve for ``lev``
    (:func:`solver`'s arguments) and the arguments it takes besides the start (the held
    ``vals`` and the level's fitted pixels)."""
    # a profile's top and bottom are read at the rim, with the disc they correlate with; a
    # constant film's thickness is read over the whole film and keeps one ray a block
    # (:data:`RIM_SAMPLES`)
    rim = settings.rim_samples if table.thickness_model != "constant" else 0
    px = solve_pixels(lev, lev.cfg.chunk, rim, settings.rim_band, settings.rim_rule)
    pad = px.padded
    key = (pad.cfg, table, float(solver.robust_scale), int(max_steps or solver.max_steps), float(solver.rtol),
           float(solver.atol), MAX_REJECTIONS if settings.stall else None, settings.jacobian,
           tuple(settings.compile_options), None if px.samples is None else (px.samples, settings.rim_rule))
    args = (held_values(table, vals), env, pad.bg, pad.bg_sigma, px.y, px.w, pad.base, px.rays)
    return key, args, px


def prepare_local(lev: Level, table: ParameterTable, solver: SolverSettings, vals: dict, env, max_steps=None,
                  settings: SolveSettings = SolveSettings()) -> None:
    """Start compiling (unless stored: its call loads it) the program of :func:`~bubblefit.inverse._local.solve_local` with these arguments
    in the background (:meth:`bubblefit.io.executables.Stored.prepare`): a fit calls it for
    its final solve before the global search, whose own programs compile meanwhile. Only
    the shapes of ``vals`` and the level count; without the executable store (library
    calls) the program is compiled in the background all the same, not saved."""
    key, args, _ = solve_program(lev, table, solver, vals, env, max_steps, settings)
    stored_solver(*key).prepare(table.unconstrained(vals), args)


def prepare_reporter(table: ParameterTable, vals: dict) -> None:
    """Start compiling (unless stored: its call loads it) :func:`reporter`'s programs in the background, for a
    solution of ``table`` held at ``vals`` (the standard errors, :mod:`._uncertainty`)."""
    z, fixed = table.unconstrained(vals), held_values(table, vals)
    for program in reporter(table):
        program.prepare(z, fixed)



def render_level(p, lev: Level, env, cfg: RenderConfig | None = None, terms: bool = False):
    """:func:`~bubblefit.model.programs.render_loaded` of ``lev`` (with ``cfg``, another
    configuration of the same camera) through its padded program: ``p``'s disc refinement
    is composed with the level's disc; the image (and with ``terms`` the dict of terms) on
    ``lev``'s pixels."""
    pad, p = _padded_params(p, lev, cfg)
    out = render_loaded(p, pad.cfg, env, pad.bg, terms=terms)
    if terms:
        return unpadded(lev, out[0]), {k: unpadded(lev, v) for k, v in out[1].items()}
    return unpadded(lev, out)


def prepare_render_level(p, lev: Level, env, cfg: RenderConfig | None = None, terms: bool = False) -> None:
    """Start compiling (unless stored: its call loads it) :func:`render_level`'s program for these arguments in
    the background (:func:`~bubblefit.model.programs.prepare_loaded`); only their shapes count."""
    pad, p = _padded_params(p, lev, cfg)
    prepare_loaded(p, pad.cfg, env, pad.bg, terms=terms)


#: Pixels beyond the disc's rim that :func:`render_bubble` still renders: the sub-pixel
#: rays of ``samples_per_pixel`` reach half a pixel's diagonal, and float32 rounding.
RIM_MARGIN_PX = 1.5


def bubble_list(p, lev: Level, skip: np.ndarray | None = None) -> tuple[Padded, Pixels | None, object]:
    """``(padded level, list, p)`` for :func:`render_bubble`: the pixels whose centre lies
    within :data:`RIM_MARGIN_PX` of the disc that ``p``'s refinement moves the level's disc
    to, less the flat indices ``skip`` (``None`` where the shortcut does not apply: not an
    orthographic camera, or a background other than the photo's; an empty list where
    ``skip`` holds them all), and ``p`` with that refinement composed."""
    pad, q = _padded_params(p, lev, None)
    if not (isinstance(pad.cfg.camera, OrthographicCamera) and pad.bg is not None
            and lev.cfg.effects.background == "photo"):
        return pad, None, q
    cx0, cy0, r0 = pad.cfg.camera.disc()
    a, b, s = (float(v) for v in np.asarray(q.disc))
    h, w = lev.y.shape[:2]
    rows, cols = np.mgrid[:h, :w]
    near = np.hypot(cols + 0.5 - (cx0 + a * r0), rows + 0.5 - (cy0 + b * r0)) <= r0 * (1.0 + s) + RIM_MARGIN_PX
    if skip is not None:
        near.reshape(-1)[np.asarray(skip, np.int64)] = False
        if not near.any():
            return pad, Pixels(pad, None, None, None, None, None, np.zeros(0, np.int64)), q
    return pad, fitted_pixels(lev, lev.cfg.chunk, near), q


def render_bubble(p, lev: Level, env, known: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """:func:`render_level`'s image of ``lev`` (numpy, float32), with only the pixels the
    bubble can reach rendered (:func:`bubble_list`): outside them the image is the
    background photo, which is what the render's composite puts where a ray misses the
    bubble. On a disc that fills 55 % of the photo, 0.20 s against 0.28 s for 320x320
    pixels; the same values wherever the shortcut does not apply. ``known``: ``(flat,
    values)``, pixels already shaded at ``p`` (a thickness map's fitted pixels from its
    traced rays, :meth:`~bubblefit.inverse._map_pixels.TracedCosts.pixels`), which the
    list leaves out and the image takes as they are."""
    pad, px, q = bubble_list(p, lev, None if known is None else known[0])
    if px is None:
        return render_level(p, lev, env)
    img = np.array(lev.bg, np.float32).reshape(-1, 3)
    if px.flat.size:
        vals = np.asarray(render_loaded(q, pad.cfg, env, pad.bg, pixels=(px.rows, px.cols, px.idx)))
        img[px.flat] = vals[: px.flat.size]
    if known is not None:
        img[np.asarray(known[0], np.int64)] = known[1]
    return img.reshape(lev.bg.shape)


def prepare_render_bubble(p, lev: Level, env) -> None:
    """Start compiling (unless stored: its call loads it) :func:`render_bubble`'s program in the background: for
    the list of ``p``'s disc (a refined disc whose list pads to another length compiles
    its own)."""
    pad, px, q = bubble_list(p, lev)
    if px is None:
        prepare_render_level(p, lev, env)
    else:
        prepare_loaded(q, pad.cfg, env, pad.bg, pixels=(px.rows, px.cols, px.idx))


def _padded_params(p, lev: Level, cfg: RenderConfig | None):
    """``lev`` (with ``cfg``) padded, and ``p`` with its disc refinement composed with the
    level's; a thickness map on ``lev``'s pixels padded as the image is (the padded
    program reads it at the padded image's flat indices)."""
    pad = padded(replace(lev, cfg=cfg) if cfg is not None else lev)
    q = replace(p, disc=compose_shift(pad.base, np.asarray(p.disc, np.float32)))
    h, w = lev.y.shape[:2]
    hb, wb = pad.cfg.shape
    if (pad.cfg.effects.thickness == "map" and jnp.ndim(p.thickness) == 2 and tuple(jnp.shape(p.thickness)) == (h, w)
            and (hb, wb) != (h, w)):
        q = replace(q, thickness=jnp.pad(jnp.asarray(p.thickness), ((0, hb - h), (0, wb - w))))
    return pad, q



def warm_up(st, opts: FitOptions, env, settings: SolveSettings) -> None:
    """Start compiling (unless stored: its call loads it) in the background the programs a fit that searches
    globally runs after its search: the final solve (``settings``), the final render
    (unless a thickness map is fitted: its render compiles after the map) and the
    standard errors' (:func:`prepare_local`, :func:`prepare_render_bubble`,
    :func:`prepare_reporter`). On 2 cores an empty-cache fit takes about 4 s less
    (``experiments/bench_fit.py --background-compile``). ``st``: the fit's
    :class:`~bubblefit.inverse._setup.Setup`."""
    final = final_params(st.table, st.vals, opts) if opts.thickness != "map" else None
    prepare_local(st.lev_fit, st.table, opts.solver, st.vals, env, settings=settings)
    if final is not None:
        prepare_render_bubble(final, st.level(1, opts), env)
    prepare_reporter(st.table, st.vals)
