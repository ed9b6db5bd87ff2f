"""Mitsuba plugins forest registers itself (written in Python).

:func:`register_all` is called by :func:`forest.runtime.mitsuba` each time a
variant is set; each plugin module builds its class for the active variant.

* ``forest_leaf`` — thin-leaf BSDF with diffuse transmission (:mod:`forest.plugins.leaf`).
* ``forest_product`` — product of two textures (:mod:`forest.plugins.product`).
"""

from __future__ import annotations

from . import leaf, product

PLUGINS = (leaf, product)


def register_all(mi) -> None:
    """Register every plugin for the currently active Mitsuba variant."""
    for module in PLUGINS:
        module.register(mi)
