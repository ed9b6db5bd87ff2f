"""Exporters: the scene for RenderMan (RIB) and for USD pipelines.

``export_rib(config, instances, out_dir, *, renderman22=False, frames=None, library=None)``
(:mod:`forest.export.rib`) and ``export_usd(config, instances, path, *, frames=None,
library=None)`` (:mod:`forest.export.usd`) are thin writers over an
:class:`~forest.instances.InstanceSet` and the tree library; what they share —
frames, the sun's direction, species and their level-of-detail bands — is in
:mod:`forest.export.common`, and the vectorised number formatting that writes
a million trees in seconds is in :mod:`forest.export.text`.

Both keep the scene's world space (metres, Y up, right-handed) and the
InstanceSet's numbers: a tree's object-to-world matrix M = T·R·S, its
colour-map tint, its id.  ``[export]`` keys: ``lod_transition`` (RIB LOD
cross-fade, fraction of a distance, default 0.1) and ``usd_lod`` (the ``lod``
variant USD prototypes select).
"""

from __future__ import annotations

__all__ = ["export_rib", "export_usd"]


def __getattr__(name):  # import lazily: usd-core is only loaded for USD exports
    if name == "export_rib":
        from .rib import export_rib

        return export_rib
    if name == "export_usd":
        from .usd import export_usd

        return export_usd
    raise AttributeError(name)
