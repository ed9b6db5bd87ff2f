"""Pictures a compositor and a lighting TD accept.

- :mod:`~forest.imaging.view` — the view transform (``agx``, ``filmic``, ``standard``) and exposure,
  through forest's OpenColorIO config; :mod:`~forest.imaging.curves` holds its documented maths and
  :mod:`~forest.imaging.ocio_config` generates the config from it.
- :mod:`~forest.imaging.exr` — the comp-ready EXR: beauty with alpha, depth/id/species, Cryptomattes
  (:mod:`~forest.imaging.cryptomatte`), camera matrices (:mod:`~forest.imaging.camera_matrices`) and
  the colour-space tag.
- :mod:`~forest.imaging.denoise` — Open Image Denoise with albedo and normal buffers.
"""

from .camera_matrices import CameraMatrices, camera_matrices
from .cryptomatte import (
    CoverageAccumulator,
    Cryptomatte,
    Ranking,
    TreeTable,
    encode,
    extract_matte,
    forest_mattes,
    rank_coverage,
)
from .denoise import denoise, oidn_available
from .exr import write_comp_exr
from .view import DEFAULT_VIEW, EXPOSURE_RANGE, VIEWS, check_exposure, check_view, quantise, to_display, write_display

__all__ = [
    "DEFAULT_VIEW",
    "EXPOSURE_RANGE",
    "VIEWS",
    "CameraMatrices",
    "CoverageAccumulator",
    "Cryptomatte",
    "Ranking",
    "TreeTable",
    "camera_matrices",
    "check_exposure",
    "check_view",
    "denoise",
    "encode",
    "extract_matte",
    "forest_mattes",
    "oidn_available",
    "quantise",
    "rank_coverage",
    "to_display",
    "write_comp_exr",
    "write_display",
]
