"""Rendering forests with Mitsuba 3.

* :func:`render_scene` — the public entry point (CLI ``forest render``, the service).
* :mod:`forest.render.scene` — camera, lights, colour grid and terrain pieces (shared with look-dev).
* :mod:`forest.render.materials` — library parts → BSDFs per variant.
* :mod:`forest.render.instancing` — LOD, wind sway, shapegroups and instances.
"""

from .render import RenderResult, choose_variant, render_scene

__all__ = ["RenderResult", "choose_variant", "render_scene"]
