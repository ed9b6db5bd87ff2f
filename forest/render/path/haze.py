"""Aerial perspective: an exponential height fog that scatters sun and sky light once.

The medium.  Haze thins with height: its extinction coefficient at height y is

    σ(y) = σ₀ · exp(−(y − y₀) / H)

with σ₀ the extinction per metre at the ground (``[render] haze``), y₀ the
lowest point of the terrain and H the scale height (``[render] haze_height``).

Transmittance along a segment x(s) = o + s·d, s ∈ [0, ℓ] (|d| = 1), from the
closed-form optical depth of an exponential atmosphere (Wenzel 2006, "Real-time
atmospheric effects in games"; Quílez 2010, "Better fog"):

    τ(ℓ) = ∫₀^ℓ σ(o_y + s·d_y) ds = σ(o_y) · ℓ · φ(ℓ·d_y / H),    φ(x) = (1 − e^(−x)) / x   (φ(0) = 1)
    T(ℓ) = exp(−τ(ℓ))

In-scattering.  With a single-scattering albedo of 1 and the light arriving at
the haze taken as the light the sky and sun send to the ground (so it is the
same at every point of the segment: sun shafts — the haze's own shadows — are
not modelled), the radiance the haze adds along the segment toward the viewer is

    L_in = ∫₀^ℓ T(s) σ(s) J(d) ds = (1 − T(ℓ)) · J(d)

because dT/ds = −σ T.  This is the aerial-perspective model of Hoffman &
Preetham (2002, "Rendering outdoor light scattering in real time",
L = L₀·F_ex + L_in with L_in ∝ (1 − F_ex)), here with a height-varying density.
The source J is an ambient term plus the sun scattered toward the viewer by a
Henyey–Greenstein phase function (Henyey & Greenstein 1941):

    J(d) = C + E_sun · p_HG(d · s; g),    p_HG(μ; g) = (1 − g²) / (4π (1 + g² − 2gμ)^(3/2))

C is ``[render] haze_colour`` (the radiance the haze tends to away from the
sun; by default the sky's mean radiance over the upper hemisphere), E_sun the
sun's irradiance (RGB, facing the sun), s the unit vector toward the sun and g
the anisotropy ``[render] haze_anisotropy`` (0.7: the forward peak of aerosol
haze, Mie scattering; 0 isotropic).  Looking toward the sun (d ≈ s) the haze
glows; away from it it tends to C.

Where it applies (:mod:`.integrator`): every camera and bounce segment that
ends on a surface, and a camera ray that leaves the scene up to
:attr:`HazeModel.sky_distance` (the end of the ground: the sky right above a
distant ridge is hazed at least as much as the ridge, so skylines stay clean).
Shadow rays and bounce rays that reach the sky are not hazed — sun and sky are
defined as the light arriving at the ground — which keeps next-event
estimation and BSDF sampling estimating the same integral.

Visibility.  ``[render] visibility`` V (km) sets σ₀ by Koschmieder's law
(Koschmieder 1924; WMO meteorological optical range at a 2 % contrast threshold):
a black object at distance V keeps 2 % contrast against the horizon sky,
e^(−σ₀ V) = 0.02, so

    σ₀ = −ln(0.02) / V = 3.912 / V                                    (:func:`density_from_visibility`)

Clear air is V ≈ 20–50 km, light haze 10–20 km, haze 4–10 km, mist 1–2 km.

The sky through the haze.  A camera ray that escapes runs up to ``sky_distance``
(≥ 30 km with the ground skirt), so toward an elevation θ above the horizon it
crosses the whole column: τ_sky(θ) ≈ σ₀ H / sin θ (the ``ℓ → ∞`` limit of τ(ℓ)
above, the camera near the ground).  At the zenith τ = σ₀ H = 3.912 H / V: the
optical depth of the column grows with H, and (1 − T) of the sky's own colour is
replaced by C, the sky's *mean* — a greyer, brighter blue.  The sky model (Hosek–Wilkie,
turbidity) already contains the real atmosphere's aerosol, so the haze here
stands only for the air in and near the scene: a shallow layer.  The default
H = 150 m keeps the demo's sky (looking up 25°, from 95 m) at 93 % of its clear HSV saturation at V = 12 km
(600 m, the former default: 61 %; hue unchanged, 215°; measured in ``bench/bench_atmosphere.py``,
``tests/test_atmosphere.py``).  The price: the haze thins faster with height, so a
camera high above the valley sees less of it — a level ray at height h meets
σ₀·e^(−h/H); give a larger ``haze_height`` for a deep haze layer (a sky that greys).

Valley fog (optional, ``[render] valley_fog``).  A second layer that pools in
low ground: constant extinction ρ up to a height y_t (the fog's ``top``) and
exponential above it with its own scale height F (the ``falloff``):

    σ_f(y) = ρ · min(1, exp(−(y − y_t) / F))

Its optical depth along the segment is in closed form (:func:`fog_depth_np`): the
part of the segment below y_t (length ℓ_b, from the crossing s_c = (y_t − o_y)/d_y)
contributes ρ·ℓ_b, and the part above (length ℓ_a, lowest point y_lo) the
exponential integral taken upward from its lowest point,

    τ_f = ρ · (ℓ_b + ℓ_a · e^(−(y_lo − y_t)/F) · φ(ℓ_a·|d_y| / F)),

which is stable for any height (φ's argument is ≥ 0).  The fog scatters the
same light as the haze (J above; one phase function and source for both), so the
two media add: T = exp(−τ − τ_f) and L_in = (1 − T)·J stay exact.

The same formulas in numpy (:func:`transmittance_np`, :func:`source_np`) serve
the ``scalar_rgb`` renderer's post-process, so both renderers share one model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from .emitters import SunTerm

#: |x| below which φ(x) = (1 − e^(−x))/x is evaluated by its Taylor series (float32 cancellation).
SERIES_BELOW = 1e-3
#: Largest −x passed to exp in φ (beyond it the segment is opaque anyway).
MAX_NEG_EXPONENT = 60.0
#: −ln(0.02): Koschmieder's constant (a 2 % contrast threshold), σ₀ = KOSCHMIEDER / V.
KOSCHMIEDER = 3.912


def density_from_visibility(visibility_km: float) -> float:
    """σ₀ (1/m) of a meteorological visibility V (km): σ₀ = 3.912 / (1000 V) (Koschmieder 1924)."""
    return KOSCHMIEDER / (1000.0 * float(visibility_km))


def visibility_from_density(density: float) -> float:
    """V (km) of a ground extinction σ₀ (1/m): V = 3.912 / (1000 σ₀); infinite for σ₀ = 0."""
    return math.inf if density <= 0.0 else KOSCHMIEDER / (1000.0 * float(density))


@dataclass(frozen=True)
class FogLayer:
    """A valley fog (see the module docstring): extinction ``density`` ρ (1/m) up to the absolute height
    ``top`` y_t (m), thinning by e every ``falloff`` F (m) above it."""

    density: float
    top: float
    falloff: float = 15.0

    def validate(self) -> None:
        """Raise ``ForestError`` unless ρ > 0, F > 0 and y_t finite."""
        from ...errors import ForestError

        if not (math.isfinite(self.density) and self.density > 0.0):
            raise ForestError(f"path inputs: valley fog density must be > 0, got {self.density}")
        if not (math.isfinite(self.falloff) and self.falloff > 0.0):
            raise ForestError(f"path inputs: valley fog falloff must be > 0, got {self.falloff}")
        if not math.isfinite(self.top):
            raise ForestError(f"path inputs: valley fog top must be finite, got {self.top}")


@dataclass(frozen=True)
class HazeInputs:
    """The haze of a frame (see the module docstring).

    ``density`` σ₀ (1/m at ``ground``), ``height`` H (m), ``colour`` C (RGB
    radiance; None: the sky's mean radiance over the upper hemisphere),
    ``anisotropy`` g ∈ (−1, 1), ``ground`` y₀ (m), ``sky_distance`` (m): how
    far a camera ray that leaves the scene is hazed; ``fog`` the valley fog (None: none).
    """

    density: float
    height: float = 150.0
    colour: tuple[float, ...] | None = None  # three values (checked)
    anisotropy: float = 0.7
    ground: float = 0.0
    sky_distance: float = 20_000.0
    fog: FogLayer | None = None

    def validate(self) -> None:
        """Raise ``ForestError`` unless density ≥ 0, height > 0, g ∈ (−1, 1) and the colour a non-negative RGB."""
        from ...errors import ForestError

        if not (math.isfinite(self.density) and self.density >= 0.0):
            raise ForestError(f"path inputs: haze density must be ≥ 0, got {self.density}")
        if not (math.isfinite(self.height) and self.height > 0.0):
            raise ForestError(f"path inputs: haze height must be > 0, got {self.height}")
        if not -1.0 < float(self.anisotropy) < 1.0:
            raise ForestError(f"path inputs: haze anisotropy must be in (−1, 1), got {self.anisotropy}")
        if self.colour is not None and (len(tuple(self.colour)) != 3 or min(self.colour) < 0.0):
            raise ForestError(f"path inputs: haze colour must be a non-negative RGB triple, got {self.colour}")
        if self.fog is not None:
            self.fog.validate()


# ---------------------------------------------------------------------------------------------
# numpy (the scalar renderer's post-process, tests)
# ---------------------------------------------------------------------------------------------


def phi_np(x: np.ndarray) -> np.ndarray:
    """φ(x) = (1 − e^(−x))/x, with its series 1 − x/2 + x²/6 near 0."""
    x = np.asarray(x, np.float64)
    small = np.abs(x) < SERIES_BELOW
    safe = np.where(small, 1.0, np.maximum(x, -MAX_NEG_EXPONENT))
    return np.where(small, 1.0 - x / 2.0 + x * x / 6.0, -np.expm1(-safe) / safe)


def transmittance_np(
    origin_y: npt.ArrayLike, direction_y: npt.ArrayLike, length: npt.ArrayLike, haze: HazeInputs
) -> np.ndarray:
    """T(ℓ) of segments starting at height ``origin_y`` with unit-direction y component ``direction_y``."""
    oy = np.asarray(origin_y, np.float64)
    sigma = haze.density * np.exp(-(oy - haze.ground) / haze.height)
    ell = np.asarray(length, np.float64)
    tau = sigma * ell * phi_np(ell * np.asarray(direction_y, np.float64) / haze.height)
    if haze.fog is not None:
        tau = tau + fog_depth_np(oy, direction_y, ell, haze.fog)
    return np.exp(-tau)


def fog_depth_np(
    origin_y: npt.ArrayLike, direction_y: npt.ArrayLike, length: npt.ArrayLike, fog: FogLayer
) -> np.ndarray:
    """τ_f of the valley fog along segments (module docstring): ρ·(ℓ_b + ℓ_a·e^(−(y_lo − y_t)/F)·φ(ℓ_a|d_y|/F))."""
    oy = np.asarray(origin_y, np.float64)
    dy = np.asarray(direction_y, np.float64)
    ell = np.asarray(length, np.float64)
    flat = np.abs(dy) < 1e-12
    sc = np.clip((fog.top - oy) / np.where(flat, 1.0, dy), 0.0, ell)  # the crossing of y = y_t, clamped
    below = np.where(flat, np.where(oy < fog.top, ell, 0.0), np.where(dy > 0.0, sc, ell - sc))
    above = ell - below
    y_lo = np.where(flat, oy, oy + sc * dy)  # the lowest point of the part above y_t
    rise = np.maximum(y_lo - fog.top, 0.0) / fog.falloff
    part = above * np.exp(-rise) * phi_np(above * np.abs(dy) / fog.falloff)
    return fog.density * (below + part)


def hg_np(mu: npt.ArrayLike, g: float) -> np.ndarray:
    """Henyey–Greenstein phase function p(μ; g), per steradian."""
    mu = np.asarray(mu, np.float64)
    return (1.0 - g * g) / (4.0 * math.pi * np.power(1.0 + g * g - 2.0 * g * mu, 1.5))


def source_np(
    directions: np.ndarray,
    haze: HazeInputs,
    sun_direction: npt.ArrayLike | None,
    sun_irradiance: npt.ArrayLike | None,
) -> np.ndarray:
    """J(d) (…, 3) for unit view directions ``directions`` (…, 3) (propagation away from the viewer)."""
    d = np.asarray(directions, np.float64)
    c = np.asarray(haze.colour if haze.colour is not None else (0.0, 0.0, 0.0), np.float64)
    if sun_direction is None or sun_irradiance is None:
        return np.broadcast_to(c, d.shape[:-1] + (3,)).copy()
    s = np.asarray(sun_direction, np.float64)
    s = s / np.linalg.norm(s)
    p = hg_np(d @ s, float(haze.anisotropy))
    return c + p[..., None] * np.asarray(sun_irradiance, np.float64)


# ---------------------------------------------------------------------------------------------
# drjit (forest_path)
# ---------------------------------------------------------------------------------------------


class HazeModel:
    """The haze as the path tracer evaluates it, its parameters read from ``PathScene.params``.

    ``params["haze_density"]``, ``["haze_height"]``, ``["haze_anisotropy"]`` (Float) and
    ``["haze_colour"]`` (Color3f) may carry gradients; the sun term takes the sun light's
    current scale (``sun`` = (direction, a function scale → RGB irradiance, that scale)).
    """

    PARAMS = ("haze_density", "haze_height", "haze_colour", "haze_anisotropy")

    def __init__(self, mi: Any, haze: HazeInputs, params: dict[str, Any], sun: SunTerm | None):
        self.mi = mi
        self.ground = float(haze.ground)
        self.sky_distance = float(haze.sky_distance)
        self.density = params["haze_density"]
        self.height = params["haze_height"]
        self.colour = params["haze_colour"]
        self.g = params["haze_anisotropy"]
        self.sun = sun
        self.fog = haze.fog

    @staticmethod
    def initial_params(mi: Any, haze: HazeInputs) -> dict[str, Any]:
        """The haze's scene parameters (:attr:`PARAMS`) at ``haze``'s values, as drjit scalars (no colour: black)."""
        return {
            "haze_density": mi.Float(float(haze.density)),
            "haze_height": mi.Float(float(haze.height)),
            "haze_colour": mi.Color3f(*[float(c) for c in (haze.colour or (0.0, 0.0, 0.0))]),
            "haze_anisotropy": mi.Float(float(haze.anisotropy)),
        }

    def transmittance(self, o: Any, d: Any, length: Any) -> Any:
        """T(ℓ) of the segments o + s·d, s ∈ [0, ``length``] (Float)."""
        import drjit as dr

        inv_h = dr.rcp(self.height)
        sigma = self.density * dr.exp(-(o.y - self.ground) * inv_h)
        x = length * d.y * inv_h
        small = dr.abs(x) < SERIES_BELOW
        xs = dr.select(small, 1.0, dr.maximum(x, -MAX_NEG_EXPONENT))
        phi = dr.select(small, 1.0 - x * 0.5 + x * x * (1.0 / 6.0), (1.0 - dr.exp(-xs)) / xs)
        if self.fog is None:
            return dr.exp(-sigma * length * phi)
        return dr.exp(-(sigma * length * phi + self.fog_depth(o.y, d.y, length)))

    def fog_depth(self, oy: Any, dy: Any, length: Any) -> Any:
        """τ_f of the valley fog along the segments (the drjit twin of :func:`fog_depth_np`)."""
        import drjit as dr

        fog = self.fog
        assert fog is not None
        flat = dr.abs(dy) < 1e-12
        sc = dr.clip((fog.top - oy) / dr.select(flat, 1.0, dy), 0.0, length)
        below = dr.select(flat, dr.select(oy < fog.top, length, 0.0), dr.select(dy > 0.0, sc, length - sc))
        above = length - below
        y_lo = dr.select(flat, oy, oy + sc * dy)
        rise = dr.maximum(y_lo - fog.top, 0.0) * (1.0 / fog.falloff)
        x = above * dr.abs(dy) * (1.0 / fog.falloff)
        small = x < SERIES_BELOW
        xs = dr.select(small, 1.0, x)
        phi = dr.select(small, 1.0 - x * 0.5 + x * x * (1.0 / 6.0), (1.0 - dr.exp(-xs)) / xs)
        return fog.density * (below + above * dr.exp(-rise) * phi)

    def source(self, d: Any) -> Any:
        """J(d) (Color3f): the ambient colour plus the sun through the Henyey–Greenstein phase function."""
        import drjit as dr

        mi = self.mi
        J = mi.Color3f(self.colour)
        if self.sun is None:
            return J
        direction, irradiance_of, scale = self.sun
        mu = dr.dot(d, mi.Vector3f(*[float(v) for v in direction]))
        g = self.g
        denom = 1.0 + g * g - 2.0 * g * mu
        p = (1.0 - g * g) * dr.rcp(4.0 * dr.pi * denom * dr.sqrt(denom))
        return J + irradiance_of(scale) * p
