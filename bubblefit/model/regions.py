"""Rendering a scene by regions: each region of pixels with its own effects
(:class:`bubblefit.model.auto.Plan`), the pixels a footprint already lit shaded from it.

The regions compose exactly, because a pixel's value does not depend on the other pixels
(:func:`render_plan`). The programs each region runs are handed in (:class:`Programs`):
this module compiles nothing itself and does not know the executable store
(:mod:`bubblefit.model.programs` does).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass

import jax
import numpy as np

from ..lighting.envmap import EnvMap
from .footprint import filter_key
from .geometry import DivergentCamera, OrthographicCamera, hit_pixels
from .render import (Params, RenderConfig, chunk_size, film_names, pixel_chunks, render, render_pixels,
                     shade_lit)

__all__ = ["Programs", "JITTED", "render_plan", "bubble_pixels", "lit_usable", "lit_chunks", "lit_program"]


@dataclass(frozen=True)
class Programs:
    """Where :func:`render_plan` takes its compiled programs from: each field maps a
    :class:`~bubblefit.model.render.RenderConfig` to a callable.

    Attributes
    ----------
    whole : Callable
        ``cfg -> (p, env, background) -> (H, W, 3)``: :func:`~bubblefit.model.render.render`.
    pixels : Callable
        ``cfg -> (p, env, background, rows, cols, idx) -> (N, 3)``:
        :func:`~bubblefit.model.render.render_pixels`.
    lit : Callable
        ``cfg -> (p, lit) -> (N, 3)``: :func:`lit_program`, shading from a footprint.
    """

    whole: Callable
    pixels: Callable
    lit: Callable


def lit_program(cfg: RenderConfig) -> Callable:
    """``(p, lit) -> (N, 3)``: :func:`~bubblefit.model.render.shade_lit` over the chunks of
    :func:`lit_chunks`, for ``cfg`` (not jitted)."""
    return lambda p, lit: jax.lax.map(lambda c: shade_lit(p, cfg, c), lit).reshape(-1, 3)


@functools.lru_cache(maxsize=32)
def _jitted_whole(cfg: RenderConfig):
    return jax.jit(lambda p, env, bg: render(p, cfg, env, bg))


@functools.lru_cache(maxsize=32)
def _jitted_pixels(cfg: RenderConfig):
    return jax.jit(lambda p, env, bg, rows, cols, idx: render_pixels(p, cfg, env, bg, rows, cols, idx))


@functools.lru_cache(maxsize=32)
def _jitted_lit(cfg: RenderConfig):
    return jax.jit(lit_program(cfg))


#: Plain ``jax.jit`` programs, compiled in this process (:func:`render_plan`'s default).
JITTED = Programs(whole=_jitted_whole, pixels=_jitted_pixels, lit=_jitted_lit)


def lit_usable(fp, p: Params, cfg: RenderConfig) -> bool:
    """Whether ``cfg``'s pixels can be shaded from the footprint ``fp``: its rays and lookups
    are the ones this render would trace (one ray per pixel read at its centre direction, as the footprint's trace
    reads it: no pixel footprint; the camera's own disc, a filter ``fp`` measured, the same parameters and the same
    lights; a divergent camera's view)."""
    fx = cfg.effects
    if fp is None or cfg.samples_per_pixel != 1 or cfg.pixel_footprint or filter_key(fx.filtering) not in fp.spec:
        return False
    if np.any(np.asarray(p.disc) != 0) and isinstance(cfg.camera, OrthographicCamera):
        return False
    names = film_names(fx)
    if any(n not in fp.films for n in names):
        return False
    if fx.environment != fp.environment or bool(fx.point_lights and cfg.point_lights) != fp.lights:
        return False
    same = lambda a, b: np.allclose(np.asarray(a, dtype=np.float32), np.asarray(b, dtype=np.float32), rtol=1e-6,
                                    atol=0.0)
    # a footprint does not record the profile under a map: shade from it only when there is none
    no_profile = fx.thickness != "map" or bool(np.isnan(np.asarray(p.profile)[0]))
    return (same(p.roughness, fp.roughness) and same(p.rotation, fp.rotation) and no_profile
            and (not isinstance(cfg.camera, DivergentCamera) or same(p.view, fp.view))
            and same(np.asarray(p.thickness).ravel(), np.asarray(fp.thickness).ravel()))


def lit_chunks(fp, cfg: RenderConfig, pixels, chunk: int, dtype=np.float32):
    """The footprint's values for ``pixels`` (flat indices, all in ``fp.pixels``), padded
    and split into chunks of ``chunk`` along a leading axis, as :func:`shade_lit` reads them."""
    fx = cfg.effects
    pos = np.searchsorted(fp.pixels, pixels)
    n = pos.size
    steps = -(-n // chunk)
    pos = pos[np.minimum(np.arange(steps * chunk), n - 1)]
    spec = fp.spec[filter_key(fx.filtering)]
    films = [fp.films.index(name) for name in film_names(fx)]
    lit = {"cos": fp.cos[pos].reshape(steps, chunk), "d0": fp.d0[pos].reshape(steps, chunk),
           "d1": fp.d1[pos].reshape(steps, chunk), "bg": fp.bg[pos].reshape(steps, chunk, 3),
           "spec": spec[films][:, pos].reshape(len(films), steps, chunk, 3).transpose(1, 0, 2, 3),
           "irr": fp.irr[:, pos].reshape(2, steps, chunk, 3).transpose(1, 0, 2, 3)}
    if fx.thickness != "constant" and fx.model == "physical" and fx.rear_reflection and fx.bounces:
        lit["dq"] = fp.dq[: fx.bounces, pos].reshape(fx.bounces, steps, chunk).transpose(1, 0, 2)
    return {k: np.ascontiguousarray(v, dtype=dtype) for k, v in lit.items()}, n


def _backdrop(cfg: RenderConfig) -> RenderConfig:
    """``cfg`` with every term of the bubble off: the image of what lies behind it (the
    background photo, the map, or black), shaded like any pixel the bubble misses."""
    fx = cfg.effects
    off = dataclasses.replace(fx, front_reflection=False, rear_reflection=False, transmission=False,
                              interference="off", diffuse=False, point_lights=False, spectral=None, bounces=0,
                              tint=False)
    return dataclasses.replace(cfg, effects=off, dispersion=None)


def bubble_pixels(cfg: RenderConfig, view: float = 0.0) -> np.ndarray:
    """Flat indices of the pixels the bubble can touch: those whose centre ray hits it
    (:func:`~bubblefit.model.geometry.hit_pixels`, through a divergent camera's view
    ``view``, :attr:`~bubblefit.model.render.Params.view`), grown by one pixel, which
    covers the sub-pixel rays of ``samples_per_pixel`` and the rounding at the rim."""
    h, w = cfg.shape
    inside = np.zeros(h * w, dtype=bool)
    inside[hit_pixels(cfg.camera, tuple(cfg.center), float(cfg.radius), float(view))] = True
    inside = inside.reshape(h, w)
    grown = inside.copy()
    grown[1:] |= inside[:-1]
    grown[:-1] |= inside[1:]
    grown[:, 1:] |= grown[:, :-1].copy()
    grown[:, :-1] |= grown[:, 1:].copy()
    return np.flatnonzero(grown)


def render_plan(p: Params, parts, env: EnvMap | None, background=None, *, footprint=None,
                programs: Programs | None = None) -> np.ndarray:
    """The (H, W, 3) image of a scene rendered by regions (:class:`bubblefit.model.auto.Plan`).

    ``parts`` pairs :class:`RenderConfig` with flat pixel indices: the first (indices
    None) renders every pixel of the bubble the others do not name, each next one its own
    pixels with its own effects. Pixels the bubble cannot touch (:func:`bubble_pixels`)
    take the backdrop (:func:`_backdrop`), which no bubble term is traced for. A pixel's
    value does not depend on the other pixels, so the regions compose exactly.

    With ``footprint`` (the scene's :class:`~bubblefit.model.footprint.Footprint`, traced
    with these parameters) a region of one ray per pixel is shaded from the light the
    footprint already read (:func:`shade_lit`): the same values, without a second pass
    over the map. Its pixels that the bubble misses keep the backdrop, as they would here.

    ``programs`` gives the compiled programs each region runs (:class:`Programs`; default
    :data:`JITTED`, plain ``jax.jit``): the caller decides where they come from (a scene
    renders through :data:`bubblefit.model.programs.STORED`, the executable store).
    """
    programs = programs or JITTED
    cfg0 = parts[0][0]
    h, w = cfg0.shape
    img = np.array(programs.whole(_backdrop(cfg0))(p, env, background)).reshape(-1, 3)
    if np.any(np.asarray(p.disc) != 0) and isinstance(cfg0.camera, OrthographicCamera):
        covered = np.arange(h * w)  # a shifted disc: the camera's own disc does not bound it
    else:
        covered = bubble_pixels(cfg0, float(p.view))
    named = [np.asarray(px, dtype=np.int64).ravel() for _, px in parts[1:] if px is not None and len(px)]
    rest = np.setdiff1d(covered, np.concatenate(named)) if named else covered
    for cfg, pixels in [(cfg0, rest)] + [(c, px) for c, px in parts[1:]]:
        if pixels is None or len(pixels) == 0:
            continue
        pixels = np.asarray(pixels, dtype=np.int64).ravel()
        if lit_usable(footprint, p, cfg):
            pixels = pixels[np.isin(pixels, footprint.pixels)]
            if pixels.size == 0:
                continue
            lit, npix = lit_chunks(footprint, cfg, pixels, chunk_size(cfg, pixels.size), np.dtype(p.t.dtype))
            vals = programs.lit(cfg)(p, lit)
        else:
            rows, cols, idx, npix = pixel_chunks(cfg, pixels)
            vals = programs.pixels(cfg)(p, env, background, rows, cols, idx)
        img[pixels] = np.asarray(vals)[:npix]
    return img.reshape(h, w, 3)
