"""Rendering forests with Mitsuba 3.

* :func:`render_scene` — the public entry point (CLI ``forest render``, the service): a Scene → EXR + PNG.
* :mod:`forest.render.loop` — the frame recipe, once: levels of detail, sub-frames, seeds, sample passes,
  first hits, depth/id/species, denoising — over a small ``Backend`` protocol.
* :mod:`forest.render.jit_frame` — forest_path's backend (:mod:`forest.render.path`, the JIT variants).
* :mod:`forest.render.frame` — Mitsuba's own integrators as a backend (``scalar_rgb``, the reference).
* :mod:`forest.render.variant` — which Mitsuba variant, and why.
* :mod:`forest.render.post` — scalar_rgb's aerial perspective after the fact.
* :mod:`forest.render.scene` — camera, lights, colour grid and terrain as Mitsuba scene dicts.
* :mod:`forest.render.materials` — library parts → Mitsuba BSDFs for ``scalar_rgb``.
* :mod:`forest.render.instancing` — shapegroups and instances (the sway is :mod:`forest.wind`).
"""

from .render import RenderResult, render_image, render_scene
from .variant import choose_variant

__all__ = ["RenderResult", "choose_variant", "render_image", "render_scene"]
