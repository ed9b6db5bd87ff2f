"""Colour maths for look-dev: linear sRGB → CIELAB / Oklab, CIEDE2000, luminance.

The numpy side uses colour-science throughout (``RGB_to_XYZ``, ``XYZ_to_Lab``,
``XYZ_to_Oklab``, ``delta_E(method="CIE 2000")``).  The optimiser needs Oklab
*inside* the differentiable render graph, so :func:`oklab_dr` re-expresses the
same transform with drjit arithmetic, taking every matrix from colour-science:

    XYZ = M_sRGB · rgb                     (IEC 61966-2-1, D65)
    LMS = M₁ · XYZ,   LMS' = ∛LMS,   Lab = M₂ · LMS'     (Ottosson 2020, "A perceptual
                                                          colour space for image processing")

Luminance is CIE Y of linear sRGB: ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (the
second row of ``M_sRGB``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt


def _colour() -> Any:
    import colour

    return colour


def srgb_matrix() -> np.ndarray:
    """Linear sRGB → CIE XYZ (D65), from colour-science."""
    return np.asarray(_colour().models.RGB_COLOURSPACE_sRGB.matrix_RGB_to_XYZ, dtype=np.float64)


def luminance_weights() -> np.ndarray:
    """CIE Y weights of linear sRGB (the second row of the sRGB → XYZ matrix)."""
    return srgb_matrix()[1].copy()


def luminance(rgb: npt.ArrayLike) -> np.ndarray:
    """CIE Y of linear sRGB values ``(..., 3)``."""
    return np.asarray(rgb, dtype=np.float64) @ luminance_weights()


def rgb_to_xyz(rgb: npt.ArrayLike) -> np.ndarray:
    """Linear sRGB → CIE XYZ (D65) (colour-science)."""
    c = _colour()
    cs = c.models.RGB_COLOURSPACE_sRGB
    return c.RGB_to_XYZ(np.asarray(rgb, dtype=np.float64), cs, apply_cctf_decoding=False)


def xyz_to_rgb(xyz: npt.ArrayLike) -> np.ndarray:
    """CIE XYZ (D65) → linear sRGB (colour-science)."""
    c = _colour()
    cs = c.models.RGB_COLOURSPACE_sRGB
    return np.asarray(c.XYZ_to_RGB(np.asarray(xyz, dtype=np.float64), cs, apply_cctf_encoding=False))


def rgb_to_lab(rgb: npt.ArrayLike) -> np.ndarray:
    """Linear sRGB → CIELAB (D65 white, colour-science)."""
    c = _colour()
    wp = c.models.RGB_COLOURSPACE_sRGB.whitepoint
    return c.XYZ_to_Lab(rgb_to_xyz(rgb), wp)


def rgb_to_oklab(rgb: npt.ArrayLike) -> np.ndarray:
    """Linear sRGB → Oklab (colour-science)."""
    return _colour().XYZ_to_Oklab(rgb_to_xyz(np.maximum(rgb, 0.0)))


def delta_e2000(rgb_a: npt.ArrayLike, rgb_b: npt.ArrayLike) -> np.ndarray:
    """CIEDE2000 between two arrays of linear sRGB colours (colour-science)."""
    return np.asarray(_colour().delta_E(rgb_to_lab(rgb_a), rgb_to_lab(rgb_b), method="CIE 2000"))


def oklab_matrices() -> tuple[np.ndarray, np.ndarray]:
    """(linear sRGB → LMS, LMS' → Lab) with LMS = M₁·M_sRGB·rgb; matrices from colour-science."""
    from colour.models import oklab

    m1 = np.asarray(oklab.MATRIX_1_XYZ_TO_LMS, dtype=np.float64) @ srgb_matrix()
    m2 = np.asarray(oklab.MATRIX_2_LMS_TO_LAB, dtype=np.float64)
    return m1, m2


def oklab_dr(r: Any, g: Any, b: Any, eps: float = 1e-5) -> tuple[Any, ...]:
    """Oklab of drjit arrays ``r, g, b`` (linear sRGB), differentiable.

    ``∛(LMS + ε)`` with a small ε keeps the derivative finite at black.
    Returns ``(L, a, b)`` drjit arrays.
    """
    import drjit as dr

    m1, m2 = oklab_matrices()
    lms = []
    for row in m1:
        v = float(row[0]) * r + float(row[1]) * g + float(row[2]) * b
        lms.append(dr.cbrt(dr.maximum(v, 0.0) + eps))
    return tuple(float(row[0]) * lms[0] + float(row[1]) * lms[1] + float(row[2]) * lms[2] for row in m2)
