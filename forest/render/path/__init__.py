"""``forest_path``: forest's path tracer for Mitsuba's JIT variants (``llvm_ad_rgb``, ``cuda_ad_rgb``).

It traces Mitsuba's traversal scene (linear in the number of instances) and
rebuilds every hit from forest's own buffers, so it never pays Mitsuba 3.9.1's
quadratic instancing cost; it evaluates forest's materials (leaves with
diffuse transmission, texture detail × colour-grid tint, alpha cut-outs for
camera, bounce and shadow rays), a finite sun and a constant, image or
physical (``sunsky``) sky with next-event estimation and multiple importance
sampling, and differentiates images with respect to the colour grid and the
light scales (path replay, reverse and forward mode).

    scene = PathScene(PathInputs(...), "llvm_ad_rgb")
    image = scene.render()            # PathImage: rgb, alpha
    layers = scene.layers()           # depth, id, species
    render_frame(inputs)              # all of it for one still
"""

from __future__ import annotations

from .frame import PathImage, PathScene, render_frame
from .inputs import Material, PathCamera, PathInputs, SkyLight, SunLight, Surface

__all__ = [
    "Material",
    "PathCamera",
    "PathImage",
    "PathInputs",
    "PathScene",
    "SkyLight",
    "SunLight",
    "Surface",
    "render_frame",
]
