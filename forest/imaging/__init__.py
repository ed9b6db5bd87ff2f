"""Pictures a compositor and a lighting TD accept.

- :mod:`forest.imaging.view` — the view transform (agx, filmic, standard) through OpenColorIO.
- :mod:`forest.imaging.curves` — the documented maths behind the shipped OCIO config.
"""

from .view import DEFAULT_VIEW, EXPOSURE_RANGE, VIEWS, check_exposure, check_view, quantise, to_display, write_display

__all__ = [
    "DEFAULT_VIEW",
    "EXPOSURE_RANGE",
    "VIEWS",
    "check_exposure",
    "check_view",
    "quantise",
    "to_display",
    "write_display",
]
