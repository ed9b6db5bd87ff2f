"""The EXR's working space: forest renders in linear Rec.709; ``[render] working_space`` picks what the EXR holds.

``rec709`` (default)
    scene-linear Rec.709 / sRGB primaries, D65 white, as Mitsuba's ``rgb`` variants
    render it; EXR header ``chromaticities`` = BT.709 + D65, ``colorInteropID`` =
    ``lin_rec709_scene``.
``acescg``
    scene-linear ACEScg (ACES AP1 primaries, ACES white ≈ D60; SMPTE ST 2065-1 /
    Academy S-2014-004): the beauty and the colour layers (``background``,
    ``albedo``, ``lightgroup.*``) are multiplied by the Rec.709 → AP1 matrix with a
    Bradford adaptation D65 → ACES white, the matrix OpenColorIO's built-in ACES
    configs use (``UTILITY - ACES-AP1_to_LINEAR-REC709_BFD``, inverted); the header
    says ``chromaticities`` = AP1 + ACES white and ``colorInteropID`` =
    ``lin_ap1_scene`` (the Color Interop Forum ID, an alias of ``ACEScg`` in OCIO's
    ``cg-config`` / ``studio-config`` and in forest's own config).

Data layers (depth, ids, normals, positions, motion, Cryptomattes) are never
converted, and the PNG is always made from the Rec.709 render through the view,
so it is the same picture in either working space.  The matrices come from
colour-science (``colour.matrix_RGB_to_RGB``), not typed in.
"""

from __future__ import annotations

import functools

import numpy as np

WORKING_SPACES = ("rec709", "acescg")
"""The values ``[render] working_space`` accepts."""
DEFAULT_WORKING_SPACE = "rec709"

INTEROP_IDS = {"rec709": "lin_rec709_scene", "acescg": "lin_ap1_scene"}
"""Color Interop Forum identifiers (OpenEXR ``colorInteropID``) of the working spaces."""

_COLOUR_NAMES = {"rec709": "ITU-R BT.709", "acescg": "ACEScg", "aces2065-1": "ACES2065-1"}


@functools.lru_cache(maxsize=8)
def rgb_matrix(source: str, target: str) -> np.ndarray:
    """3×3 float64 matrix taking linear RGB in ``source`` to ``target`` (``rec709``, ``acescg``, ``aces2065-1``),
    with a Bradford chromatic adaptation between their white points (identity when they are the same)."""
    if source == target:
        return np.eye(3)
    import colour

    spaces = colour.RGB_COLOURSPACES
    m = colour.matrix_RGB_to_RGB(
        spaces[_COLOUR_NAMES[source]], spaces[_COLOUR_NAMES[target]], chromatic_adaptation_transform="Bradford"
    )
    return np.asarray(m, dtype=np.float64)


@functools.lru_cache(maxsize=1)
def xyz_to_rec709() -> np.ndarray:
    """3×3 float64 matrix CIE XYZ (D65) → linear Rec.709 (no adaptation: both are D65)."""
    import colour

    return np.asarray(colour.RGB_COLOURSPACES["ITU-R BT.709"].matrix_XYZ_to_RGB, dtype=np.float64)


@functools.lru_cache(maxsize=4)
def chromaticities(space: str) -> tuple[float, ...]:
    """OpenEXR ``chromaticities`` of ``space``: red xy, green xy, blue xy, white xy."""
    if space == "rec709":
        return (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)  # ITU-R BT.709 primaries, D65 (the standard)
    import colour

    cs = colour.RGB_COLOURSPACES[_COLOUR_NAMES[space]]
    return tuple(float(v) for v in (*np.asarray(cs.primaries).ravel(), *np.asarray(cs.whitepoint).ravel()))


def check_working_space(space: str) -> str:
    """``space`` if it is one of :data:`WORKING_SPACES`, else ``ValueError``."""
    if space not in WORKING_SPACES:
        raise ValueError(f"unknown working space {space!r}; use one of {', '.join(WORKING_SPACES)}")
    return space


def from_rec709(rgb: np.ndarray, space: str) -> np.ndarray:
    """Linear Rec.709 ``(..., 3)`` → the same colours in ``space`` (float32; the input itself for ``rec709``)."""
    check_working_space(space)
    if space == "rec709":
        return rgb
    a = np.asarray(rgb, dtype=np.float64)
    return (a @ rgb_matrix("rec709", space).T).astype(np.float32)
