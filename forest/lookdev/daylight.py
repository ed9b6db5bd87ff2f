"""Light colours from a colour temperature: the Planckian and daylight loci in linear sRGB.

A light's colour is given by its correlated colour temperature T (kelvin) and
its distance Duv from the Planckian locus in the CIE 1960 UCS (u, v) diagram,
positive towards green (Ohno 2013, "Practical use and calculation of CCT and
Duv", *LEUKOS* 10(1): 47–55):

    (u, v) = P(T) + Duv · n(T)

with P the Planckian locus and n its unit normal.  Both are tabulated once with
colour-science (``CCT_to_uv_Ohno2013``) over a grid of mireds (10⁶/T, in which
the locus is close to uniformly spaced) and interpolated linearly, so a colour
costs a few ``np.interp`` calls and is a smooth function of T for the
optimiser.  (u, v) → xy → XYZ with Y = 1 → linear sRGB (colour-science, D65):
every colour returned here has unit CIE luminance, so a light's intensity lives
in one scalar.

The **CIE daylight locus** (D-series illuminants, CIE 15:2004 §3.1) runs
Duv ≈ +0.003 above the Planckian locus between 4000 K and 25 000 K;
:func:`daylight_duv` gives its Duv (computed from ``CCT_to_xy_CIE_D``), held at
its 4000 K value below 4000 K (where the D-series is not defined and the
reddened direct sun at low elevation is close to the Planckian locus in any
case) and at its 25 000 K value above.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

#: Mired range of the tables: 10⁶/T for T from 100 000 K down to 1 000 K.
MIRED_RANGE = (10.0, 1000.0)
MIRED_STEP = 0.5
#: D65's colour temperature (K).
D65_CCT = 6504.0


def mired(kelvin: npt.ArrayLike) -> np.ndarray:
    """10⁶ / T."""
    return 1e6 / np.asarray(kelvin, np.float64)


@lru_cache(maxsize=1)
def _tables() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(mireds, Planckian (u, v), unit normal, daylight Duv) on the mired grid."""
    import colour

    m = np.arange(MIRED_RANGE[0], MIRED_RANGE[1] + MIRED_STEP / 2, MIRED_STEP)
    t = 1e6 / m
    on = colour.temperature.CCT_to_uv_Ohno2013(np.stack([t, np.zeros_like(t)], axis=1))
    off = colour.temperature.CCT_to_uv_Ohno2013(np.stack([t, np.full_like(t, 0.01)], axis=1))
    normal = (off - on) / np.linalg.norm(off - on, axis=1, keepdims=True)
    td = np.clip(t, 4000.0, 25000.0)
    xy_d = colour.temperature.CCT_to_xy_CIE_D(td)
    uv_d = colour.xy_to_UCS_uv(xy_d)
    duv = np.einsum("ij,ij->i", uv_d - np.stack([np.interp(td, t[::-1], on[::-1, k]) for k in range(2)], 1), normal)
    return m, on, normal, duv


def daylight_duv(kelvin: npt.ArrayLike) -> np.ndarray:
    """Duv of the CIE daylight locus at ``kelvin`` (held constant outside 4000–25 000 K)."""
    m, _, _, duv = _tables()
    return np.interp(mired(kelvin), m, duv)


@lru_cache(maxsize=1)
def _xyz_to_rgb() -> np.ndarray:
    """XYZ → linear sRGB (D65): the inverse of colour-science's sRGB matrix, taken once (a fit asks for
    thousands of light colours, and a matrix product is what ``colour.XYZ_to_RGB`` computes)."""
    from .colour import srgb_matrix

    return np.linalg.inv(srgb_matrix())


def locus_rgb(kelvin: npt.ArrayLike, duv: npt.ArrayLike = 0.0) -> np.ndarray:
    """Linear sRGB with unit luminance of the colour (T, Duv); broadcasts, shape (..., 3)."""
    from .colour import luminance

    m, on, normal, _ = _tables()
    mk = np.clip(mired(kelvin), m[0], m[-1])
    d = np.asarray(duv, np.float64)
    u = np.interp(mk, m, on[:, 0]) + d * np.interp(mk, m, normal[:, 0])
    v = np.interp(mk, m, on[:, 1]) + d * np.interp(mk, m, normal[:, 1])
    # CIE 1960 (u, v) → xy (Wyszecki & Stiles 1982, Table 3(2.3.2)).
    den = 2.0 * u - 8.0 * v + 4.0
    x, y = 3.0 * u / den, 2.0 * v / den
    xyz = np.stack([x / y, np.ones_like(x), (1.0 - x - y) / y], axis=-1)
    # Below about 2500 K the locus leaves the sRGB gamut (blue < 0): clipped, as a renderer's RGB light must be.
    rgb = np.maximum(xyz @ _xyz_to_rgb().T, 1e-3)
    return rgb / luminance(rgb)[..., None]


def daylight_rgb(kelvin: npt.ArrayLike) -> np.ndarray:
    """Unit-luminance linear sRGB of daylight (the D-series locus) at ``kelvin``."""
    return locus_rgb(kelvin, daylight_duv(kelvin))


def rgb_to_cct(rgb: npt.ArrayLike) -> tuple[float, float]:
    """(T, Duv) of a linear sRGB colour (Ohno 2013, colour-science); (D65, 0) for black."""
    import colour

    from .colour import rgb_to_xyz

    c = np.maximum(np.asarray(rgb, np.float64), 0.0)
    if c.sum() <= 1e-12:
        return D65_CCT, 0.0
    uv = colour.xy_to_UCS_uv(colour.XYZ_to_xy(rgb_to_xyz(c)))
    t, duv = colour.temperature.uv_to_CCT_Ohno2013(uv)
    lo, hi = 1e6 / MIRED_RANGE[1], 1e6 / MIRED_RANGE[0]
    return float(np.clip(t, lo, hi)), float(duv)
