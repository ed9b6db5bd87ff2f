"""Rendering forests with Mitsuba 3.

* :func:`render_scene` — the public entry point (CLI ``forest render``, the service): a Scene → EXR + PNG.
* :mod:`forest.render.frame` — the frames: levels of detail, sub-frames, sample passes, depth/id/species.
* :mod:`forest.render.variant` — which Mitsuba variant, and why.
* :mod:`forest.render.post` — aerial perspective and the optional denoiser.
* :mod:`forest.render.scene` — camera, lights, colour grid and terrain as Mitsuba scene dicts.
* :mod:`forest.render.materials` — library parts → BSDFs per variant.
* :mod:`forest.render.instancing` — shapegroups and instances (the sway is :mod:`forest.wind`).
"""

from .render import RenderResult, render_image, render_scene
from .variant import choose_variant

__all__ = ["RenderResult", "choose_variant", "render_image", "render_scene"]
