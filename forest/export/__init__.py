"""Exporters: the scene for RenderMan (RIB), USD pipelines, Blender and any DCC that instances on points.

Each takes a :class:`~forest.scene.Scene`:

* ``export_rib(scene, out_dir, *, renderman22=False, frames=None, display=None, progress=None)``
  (:mod:`forest.export.rib`; the RSL shader ships in ``shaders/``);
* ``export_usd(scene, path, *, frames=None, progress=None)`` (:mod:`forest.export.usd`);
* ``export_blender(scene, path, *, blender=None, frames=None, render=None, coverage=False, timeout=None,
  progress=None)`` (:mod:`forest.export.blender`, which runs :mod:`forest.export.blender_build` in Blender);
* ``export_points(scene, path, *, progress=None)`` (:mod:`forest.export.points`).

What they share — frames, the sun's direction, species and their level-of-detail
bands, the winding of triangles, the terrain's colour, stale-file removal — is in
:mod:`forest.export.common`; light units across renderers in
:mod:`forest.export.radiometry`; the vectorised number formatting that writes a
million trees in seconds in :mod:`forest.export.text`.

All keep the scene's numbers: a tree's object-to-world matrix M = T·R·S, its
colour-map tint, its id.  ``[export]`` keys: ``lod_transition`` and ``rib_lod``
(RIB levels of detail), ``rib_display`` and ``rib_textures`` (RIB display driver
and texture files), ``usd_lod`` and ``blender_lod`` (the level USD prototypes
select and Blender instances).  See ``docs/exports.md``.
"""

from __future__ import annotations

__all__ = ["export_blender", "export_points", "export_rib", "export_usd"]


def __getattr__(name):  # import lazily: usd-core is only loaded for USD exports
    if name == "export_rib":
        from .rib import export_rib

        return export_rib
    if name == "export_usd":
        from .usd import export_usd

        return export_usd
    if name == "export_blender":
        from .blender import export_blender

        return export_blender
    if name == "export_points":
        from .points import export_points

        return export_points
    raise AttributeError(name)
