"""The maths of forest's view transforms: scene-linear Rec.709 → display-linear → sRGB.

Three views turn a scene-linear image (Rec.709/sRGB primaries, D65, 1.0 = a
perfect white diffuser under unit irradiance) into a picture for an sRGB display.
The OpenColorIO config in ``forest/imaging/ocio/`` is generated from the
functions here (``scripts/make_ocio_config.py``), and the tests check that OCIO
applying that config reproduces these reference functions.

``standard``
    Clip to [0, 1], then the IEC 61966-2-1 sRGB encoding.  18 % grey → sRGB
    code 0.4614 (117.7/255); everything above scene value 1.0 clips to white.

``filmic``
    John Hable's filmic curve (“Filmic Tonemapping Operators”, GDC 2010; the
    “Uncharted 2” operator), applied per channel to scene-linear values::

        F(x) = (x(Ax + CB) + DE) / (x(Ax + B) + DF) − E/F
        display_linear = F(k·v) / F(W)

    with Hable's published constants A = 0.15 (shoulder strength), B = 0.50
    (linear strength), C = 0.10 (linear angle), D = 0.20 (toe strength),
    E = 0.02, F = 0.30 (toe numerator/denominator) and linear white W = 11.2.
    The exposure bias k (≈ 3.59) is solved so that 18 % grey lands on display
    code 0.5: scene value W/k (≈ 3.1, +4.1 EV over grey) reaches white, shadows
    get the curve's toe.  Per-channel, so bright saturated colours skew toward
    their neighbouring secondary before they reach white.

``agx``
    An AgX-style transform after Troy Sobotka's design (AgX, 2022; as adopted
    by Blender 4.0), built here from its stated structure:

    1. **Inset**: a 3×3 matrix whose columns are the Rec.709 primaries moved
       toward the D65 white by a fraction ``a`` and rotated about it by ``θ``
       in CIE xy (``N_in = M_709⁻¹ · M_inset``, M the normalised primary matrix
       of SMPTE RP 177).  Every pure colour becomes a mixture of all three
       channels, so the per-channel curve below drives over-exposed colour
       toward white instead of clipping it into the six pure hues.
    2. **Log2 encoding** around 18 % grey over ``[EV_MIN, EV_MAX]`` =
       [−10, +6.5] stops: ``x = (log2(v / 0.18) − EV_MIN) / (EV_MAX − EV_MIN)``,
       clamped to [0, 1].
    3. **Sigmoid** ``y(x)``: two power-sigmoid halves ``g(u) = u / (1 + u^p)^(1/p)``
       joined at the grey pivot ``(x₀, y₀)`` with slope ``s``,
       ``y = y₀ ± a·g(s·|x − x₀| / a)``; the scales ``a`` are solved in closed
       form so that y(0) = 0 and y(1) = 1 exactly:
       ``a = L·s / ((L·s / D)^p − 1)^(1/p)`` with L, D the half's extent in x and y.
    4. **Decode** ``y^2.4`` to display-linear light.
    5. **Outset**: the inverse of an inset matrix with attenuation ``b`` and the
       same rotation, which undoes the hue rotation and restores mid-tone purity.
    6. Clip to [0, 1] and encode with the sRGB OETF.

    18 % grey → display code 0.5 (display-linear 0.214); white is reached at
    +6.5 EV (scene value 16.3), so sun-lit highlights roll off instead of
    clipping.  Neutral greys stay neutral (both matrices preserve white).

**Looks** (``[render] look``, agx only).  Blender's AgX ships looks that grade
the picture in AgX's log encoding, between steps 2 and 3: an ASC CDL (the
American Society of Cinematographers' Color Decision List, v1.2, 2009) of slope
S, offset O, power P and saturation σ,

    x' = clamp(x·S + O)^P,    x'' = clamp(ℓ + σ·(x' − ℓ)),    ℓ = 0.2126 x'_R + 0.7152 x'_G + 0.0722 x'_B

with clamp to [0, 1] and ℓ the Rec.709 luma (:func:`asc_cdl`).  The values are
Blender's (:data:`AGX_LOOKS`, as its OCIO config and the AgXc project list them):
``punchy`` (P = 1.35, σ = 1.4) deepens shadows and mid-tones and restores the
chroma that AgX's inset takes from bright colours (a blue sky two stops over grey
stays blue instead of going pale), at the cost of about 1.5 stops in the
mid-tones; the contrast looks scale the log encoding about its middle.

Every function takes and returns float arrays ``(..., 3)``; the EXR stays
scene-linear: these curves only make display pictures (PNG, previews).
"""

from __future__ import annotations

import functools

import numpy as np

MID_GREY = 0.18
"""Scene-linear 18 % grey, the pivot of the log encodings."""

DISPLAY_GREY = 0.5
"""The sRGB code value that 18 % grey reaches at exposure 0 in the agx and filmic views."""

# ------------------------------------------------------------------ sRGB display encoding


def srgb_oetf(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of display-linear ``v`` in [0, 1] (clipped first)."""
    v = np.clip(np.asarray(v, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1.0 / 2.4) - 0.055)


def srgb_eotf(c: np.ndarray) -> np.ndarray:
    """The inverse of :func:`srgb_oetf`: sRGB code value → display-linear light."""
    c = np.clip(np.asarray(c, dtype=np.float64), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, np.power((c + 0.055) / 1.055, 2.4))


def standard(rgb: np.ndarray) -> np.ndarray:
    """The ``standard`` view: clip, then sRGB-encode.  Returns sRGB code values in [0, 1]."""
    return srgb_oetf(rgb)


# ------------------------------------------------------------------ log2 shaper shared by the LUT views

EV_MIN = -10.0
"""Stops below 18 % grey that the log encoding keeps (0.18·2⁻¹⁰ ≈ 1.8e-4 maps to 0)."""
EV_MAX = 6.5
"""Stops above 18 % grey that the log encoding keeps (0.18·2^6.5 ≈ 16.3 maps to 1)."""


def log2_encode(v: np.ndarray) -> np.ndarray:
    """``(log2(v / 0.18) − EV_MIN) / (EV_MAX − EV_MIN)`` with v clamped to the encoded range."""
    lo, hi = MID_GREY * 2.0**EV_MIN, MID_GREY * 2.0**EV_MAX
    v = np.clip(np.asarray(v, dtype=np.float64), lo, hi)
    return (np.log2(v / MID_GREY) - EV_MIN) / (EV_MAX - EV_MIN)


def log2_decode(x: np.ndarray) -> np.ndarray:
    """The inverse of :func:`log2_encode` on [0, 1]."""
    return MID_GREY * np.exp2(np.asarray(x, dtype=np.float64) * (EV_MAX - EV_MIN) + EV_MIN)


# ------------------------------------------------------------------ filmic (Hable 2010)

HABLE = {"A": 0.15, "B": 0.50, "C": 0.10, "D": 0.20, "E": 0.02, "F": 0.30, "W": 11.2}
"""Hable's published constants (GDC 2010, “Uncharted 2: HDR Lighting”)."""


def _hable(x: np.ndarray) -> np.ndarray:
    A, B, C, D, E, F = (HABLE[k] for k in "ABCDEF")
    x = np.asarray(x, dtype=np.float64)
    return (x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F) - E / F


@functools.lru_cache(maxsize=1)
def filmic_bias() -> float:
    """Exposure bias k of the filmic view: F(0.18·k) / F(W) = display-linear of code 0.5 (solved on first use, so
    importing this module does not import SciPy's optimisers)."""
    from scipy.optimize import brentq

    target = float(srgb_eotf(np.array(DISPLAY_GREY)))
    white = float(_hable(np.array(HABLE["W"])))
    return float(brentq(lambda k: float(_hable(np.array(MID_GREY * k))) / white - target, 0.1, 100.0, xtol=1e-14))


def filmic_display_linear(v: np.ndarray) -> np.ndarray:
    """Per-channel Hable curve: scene-linear → display-linear in [0, 1]."""
    v = np.maximum(np.asarray(v, dtype=np.float64), 0.0)
    return np.clip(_hable(filmic_bias() * v) / _hable(np.array(HABLE["W"])), 0.0, 1.0)


def filmic(rgb: np.ndarray) -> np.ndarray:
    """The ``filmic`` view as a reference: the curve on the log2-shaped range, then sRGB-encode.

    Values are clamped to the log2 shaper's range first, as the OCIO config does.
    """
    v = log2_decode(log2_encode(rgb))
    return srgb_oetf(filmic_display_linear(v))


# ------------------------------------------------------------------ AgX-style (after Sobotka 2022)

REC709_PRIMARIES = np.array([[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]])
"""CIE xy of the Rec.709 / sRGB primaries (ITU-R BT.709-6)."""
D65 = np.array([0.3127, 0.3290])
"""CIE xy of the D65 white point (ITU-R BT.709-6)."""

AGX_INSET = (0.18, 0.14, 0.15)
"""Fraction by which the R, G, B primaries move toward white in the inset.

With :data:`AGX_ROTATE` every entry of the inset matrix is positive, so a
non-negative colour stays non-negative."""
AGX_ROTATE = (2.0, -1.0, -2.5)
"""Rotation of the R, G, B primaries about white in CIE xy, degrees (counter-clockwise > 0)."""
AGX_OUTSET = (0.18, 0.14, 0.15)
"""Attenuation of the matrix whose inverse is the outset (equal to the inset: mid-tone purity restored)."""

AGX_SLOPE = 2.3
"""Sigmoid slope at the grey pivot, in display code per unit of the log encoding (16.5 stops)."""
AGX_POWER_TOE = 1.4
"""Power p of the lower half of the sigmoid (smaller: a longer, softer toe)."""
AGX_POWER_SHOULDER = 1.8
"""Power p of the upper half of the sigmoid (smaller: a longer, softer shoulder)."""
AGX_DECODE_GAMMA = 2.4
"""The sigmoid's output is raised to this power to give display-linear light."""


def _inset_primaries(attenuation, rotation_deg) -> np.ndarray:
    out = np.empty((3, 2))
    for i, (a, deg) in enumerate(zip(attenuation, rotation_deg)):
        t = np.radians(deg)
        rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        out[i] = D65 + (1.0 - a) * rot @ (REC709_PRIMARIES[i] - D65)
    return out


def primaries_matrix(attenuation, rotation_deg) -> np.ndarray:
    """Columns = the moved primaries expressed in Rec.709 RGB: ``M_709⁻¹ · M_moved`` (rows sum to 1)."""
    import colour

    m709 = colour.normalised_primary_matrix(REC709_PRIMARIES, D65)
    moved = colour.normalised_primary_matrix(_inset_primaries(attenuation, rotation_deg), D65)
    return np.linalg.solve(m709, moved)


def agx_inset_matrix() -> np.ndarray:
    """The inset matrix ``N_in`` (3×3, applied as ``N_in @ rgb``)."""
    return primaries_matrix(AGX_INSET, AGX_ROTATE)


def agx_outset_matrix() -> np.ndarray:
    """The outset matrix: the inverse of the primaries matrix with attenuation ``AGX_OUTSET``."""
    return np.linalg.inv(primaries_matrix(AGX_OUTSET, AGX_ROTATE))


AGX_PIVOT_X = -EV_MIN / (EV_MAX - EV_MIN)
"""Where 18 % grey falls in the log encoding (10 / 16.5)."""
AGX_PIVOT_Y = float(srgb_eotf(np.array(DISPLAY_GREY))) ** (1.0 / AGX_DECODE_GAMMA)
"""The sigmoid's value at the pivot, so that grey decodes to the display-linear light of code 0.5."""


def _power_sigmoid(u: np.ndarray, p: float) -> np.ndarray:
    return u / np.power(1.0 + np.power(u, p), 1.0 / p)


def _half_scale(length: float, height: float, slope: float, p: float) -> float:
    ls = length * slope
    if ls <= height:
        raise ValueError("sigmoid slope too small to reach the end point")
    return ls / ((ls / height) ** p - 1.0) ** (1.0 / p)


def agx_sigmoid(x: np.ndarray) -> np.ndarray:
    """The AgX tone curve on the log encoding: [0, 1] → [0, 1], C¹, slope ``AGX_SLOPE`` at the pivot."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    x0, y0, s = AGX_PIVOT_X, AGX_PIVOT_Y, AGX_SLOPE
    a_top = _half_scale(1.0 - x0, 1.0 - y0, s, AGX_POWER_SHOULDER)
    a_bot = _half_scale(x0, y0, s, AGX_POWER_TOE)
    above = y0 + a_top * _power_sigmoid(s * np.maximum(x - x0, 0.0) / a_top, AGX_POWER_SHOULDER)
    below = y0 - a_bot * _power_sigmoid(s * np.maximum(x0 - x, 0.0) / a_bot, AGX_POWER_TOE)
    return np.clip(np.where(x >= x0, above, below), 0.0, 1.0)


AGX_LOOKS: dict[str, tuple[float, float, float, float]] = {
    "punchy": (1.0, 0.0, 1.35, 1.4),
    "very_high_contrast": (1.57, -0.114, 1.0, 0.9),
    "high_contrast": (1.4, -0.08, 1.0, 0.95),
    "medium_high_contrast": (1.2, -0.04, 1.0, 1.0),
    "medium_low_contrast": (0.9, 0.02, 1.0, 1.05),
    "low_contrast": (0.8, 0.04, 1.0, 1.1),
    "very_low_contrast": (0.7, 0.06, 1.0, 1.15),
}
"""Blender's AgX looks as ASC CDL (slope, offset, power, saturation) on the log encoding (module docstring)."""

LUMA_709 = np.array([0.2126, 0.7152, 0.0722])
"""Rec.709 luma weights, the CDL saturation's (ASC CDL v1.2)."""


def asc_cdl(x: np.ndarray, slope: float, offset: float, power: float, saturation: float) -> np.ndarray:
    """The ASC CDL v1.2 on values in [0, 1]: clamp(x·S + O)^P, then saturation σ about the Rec.709 luma, clamped."""
    x = np.clip(np.asarray(x, dtype=np.float64) * slope + offset, 0.0, 1.0) ** power
    luma = (x @ LUMA_709)[..., None]
    return np.clip(luma + saturation * (x - luma), 0.0, 1.0)


def agx_display_linear(rgb: np.ndarray, look: str | None = None) -> np.ndarray:
    """Steps 1–5 of the AgX view: scene-linear → display-linear (not yet clipped); ``look`` a key of
    :data:`AGX_LOOKS` graded on the log encoding (None: none)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    inset = rgb @ agx_inset_matrix().T
    x = log2_encode(inset)
    if look is not None:
        x = asc_cdl(x, *AGX_LOOKS[look])
    y = agx_sigmoid(x)
    return np.power(y, AGX_DECODE_GAMMA) @ agx_outset_matrix().T


def agx(rgb: np.ndarray, look: str | None = None) -> np.ndarray:
    """The ``agx`` view as a reference: scene-linear → sRGB code values in [0, 1] (``look``: see
    :func:`agx_display_linear`)."""
    return srgb_oetf(agx_display_linear(rgb, look))


REFERENCE = {"agx": agx, "filmic": filmic, "standard": standard}
"""The reference implementation of each view (numpy, float64), for tests and documentation."""
