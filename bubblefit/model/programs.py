"""The model's compiled programs, prepared, stored and loaded in one place.

Each program is jitted here and kept in the executable store
(:func:`bubblefit.io.executables.stored`): a new process loads it instead of tracing and
lowering it again. The renderer (:mod:`.render`), the regions (:mod:`.regions`) and the
footprint (:mod:`.footprint`) compile nothing against the store themselves: they take the
programs they run from here (:data:`STORED`, :func:`stored_trace`), handed in by the scene
(:func:`bubblefit.model.scene.render_scene`) or by the fit's own programs module
(:mod:`bubblefit.inverse._programs`, through :func:`render_loaded` and :func:`prepare_loaded`).
"""

from __future__ import annotations

import functools

import jax

from ..io.executables import stored
from ..lighting.envmap import EnvMap
from .footprint import trace_function
from .regions import Programs, lit_program
from .render import Params, RenderConfig, render, render_pixels, render_terms

__all__ = ["STORED", "TERMS_COMPILE", "stored_whole", "stored_pixels", "stored_terms", "stored_lit", "stored_trace",
           "render_loaded", "prepare_loaded"]


@functools.lru_cache(maxsize=32)
def _render_programs(cfg: RenderConfig):
    """:func:`~bubblefit.model.render.render` and :func:`~bubblefit.model.render.render_pixels`
    for ``cfg`` through the executable store (:func:`bubblefit.io.executables.stored`): a
    new process loads them, not traces them."""
    whole = jax.jit(lambda p, env, bg: render(p, cfg, env, bg))
    chunks = jax.jit(lambda p, env, bg, rows, cols, idx: render_pixels(p, cfg, env, bg, rows, cols, idx))
    return stored(whole, "model.render.render", cfg), stored(chunks, "model.render._render_chunks", cfg)


#: XLA's compiler options (``(name, value)`` pairs) for :func:`~bubblefit.model.render.render_terms`'s stored
#: program. A fit runs it once, on the few thousand pixels of its search image (the global
#: search's unlit terms), on the first fit's critical path; so it is compiled at XLA's
#: backend optimisation level 0 and with XLA:CPU's older per-element emitters for fused
#: loops (``xla_cpu_use_fusion_emitters``): 0.22 s of compile CPU against 1.04-1.07 s
#: with XLA's defaults, for a run of 30 ms against 8 ms (the search level of
#: ``experiments/bench_fit.py``'s 320x320 photo, compiled alone).
TERMS_COMPILE = (("xla_backend_optimization_level", 0), ("xla_cpu_use_fusion_emitters", False))


@functools.lru_cache(maxsize=16)
def stored_terms(cfg: RenderConfig):
    """:func:`~bubblefit.model.render.render_terms` for ``cfg`` through the executable store, compiled with
    :data:`TERMS_COMPILE`."""
    program = jax.jit(lambda p, env, bg: render_terms(p, cfg, env, bg), compiler_options=dict(TERMS_COMPILE))
    return stored(program, "model.render.render_terms", (cfg, TERMS_COMPILE))


def render_loaded(p: Params, cfg: RenderConfig, env: EnvMap | None, background=None, *, terms: bool = False,
                  pixels=None):
    """:func:`~bubblefit.model.render.render` (or with ``terms``,
    :func:`~bubblefit.model.render.render_terms`) through the executable store
    (:func:`bubblefit.io.executables.stored`): the same values, and a command's process
    loads the compiled program instead of tracing and lowering it. Concrete arrays only.
    With ``pixels = (rows, cols, idx)`` (chunks as :func:`~bubblefit.model.render.render_pixels` takes them), the
    radiance (N, 3) of those pixels alone (:func:`~bubblefit.model.render.render_pixels`)."""
    if pixels is not None:
        return _render_programs(cfg)[1](p, env, background, *pixels)
    return (stored_terms(cfg) if terms else _render_programs(cfg)[0])(p, env, background)


def prepare_loaded(p: Params, cfg: RenderConfig, env: EnvMap | None, background=None, *, terms: bool = False,
                   pixels=None):
    """Start compiling (unless stored: its call loads it) :func:`render_loaded`'s program for these arguments in
    the background (:meth:`bubblefit.io.executables.Stored.prepare`): a later
    :func:`render_loaded` with arguments of the same shapes waits for it instead of
    compiling. Only the shapes of the arguments count."""
    if pixels is not None:
        _render_programs(cfg)[1].prepare(p, env, background, *pixels)
    else:
        (stored_terms(cfg) if terms else _render_programs(cfg)[0]).prepare(p, env, background)


@functools.lru_cache(maxsize=32)
def stored_lit(cfg: RenderConfig):
    """:func:`~bubblefit.model.render.shade_lit` over chunks for ``cfg``, through the executable store."""
    fn = jax.jit(lit_program(cfg))
    return stored(fn, "model.render.shade_lit", cfg)



def stored_whole(cfg: RenderConfig):
    """:func:`~bubblefit.model.render.render` for ``cfg``, through the executable store."""
    return _render_programs(cfg)[0]


def stored_pixels(cfg: RenderConfig):
    """:func:`~bubblefit.model.render.render_pixels` for ``cfg``, through the executable store."""
    return _render_programs(cfg)[1]


@functools.lru_cache(maxsize=16)
def stored_trace(camera, center, radius, model, lights, background_kind, thickness_kind):
    """The footprint's trace (:func:`~bubblefit.model.footprint.trace_function`) for these
    static settings, through the executable store."""
    statics = dict(camera=camera, center=center, radius=radius, model=model, lights=lights,
                   background_kind=background_kind, thickness_kind=thickness_kind)
    return stored(jax.jit(trace_function(camera, center, radius, model, lights, background_kind, thickness_kind)),
                  "model.footprint._trace", statics)


#: The programs :func:`~bubblefit.model.regions.render_plan` runs, through the store.
STORED = Programs(whole=stored_whole, pixels=stored_pixels, lit=stored_lit)
