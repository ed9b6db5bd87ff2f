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
the haze taken as the light the sky and sun send to the ground (the same at every
point of the segment; the sun's share shadowed on camera rays with ``shafts``,
below), the radiance the haze adds along the segment toward the viewer is

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

A fog with an uneven top (``variation`` v > 0, ``variation_scale`` S).  Real
valley fog is flat-topped only where an inversion caps it; elsewhere it lies in
banks, thicker in some hollows than others.  The top then rises and falls over the
ground by up to v metres,

    y_t(x, z) = y_t + v · (2 N(x/S, z/S) − 1),

N a two-octave value noise in [0, 1) (:func:`fog_noise_np`, :func:`fog_noise`;
the lattice hash of :mod:`.clouds`).  The closed form above needs one y_t per
segment, so each segment reads the top over its *lowest end* (its end point for a
ray going down, its start for one going up or level, :func:`fog_anchor_np`) —
where the fog it crosses is densest.  This is exact for a top that is level
along the segment and an approximation where a segment runs far through the fog
with the top changing under it (a grazing ray over a fog bank sees the bank's
thickness at the point it reaches); the banks, S ≈ 100 m and more, change little
between a crown and the ground just behind it, so silhouettes do not cut the
fog's pattern.

Light shafts (``shafts``, ``[render] haze_shafts``).  The sun reaches a point of
the haze only where nothing stands between it and the sun; with a visibility
V(s) ∈ [0, 1] along the segment the sun's share of the in-scattering is

    L_sun = ∫₀^ℓ T(s) σ(s) E_sun p(d · s) V(s) ds.

Drawing s with the density σ(s)T(s) / (1 − T(ℓ)) — the distance at which light
scatters, by inverting the closed-form optical depth τ(s) = −ln(1 − u(1 − T(ℓ)))
(:meth:`HazeModel.sample_distance`, bisection) — the unshadowed value times the
visibility at that one point is an unbiased estimate of it:

    L̂_sun = (1 − T(ℓ)) · E_sun p(d · s) · V(s*),

V taken toward a point of the sun's disc drawn uniformly in its cone (:meth:`HazeModel.sun_ray`), so the
shafts' edges are soft as the disc's shadows on surfaces are.

The ambient share C keeps its closed form.  How the integrator spends its one
shadow ray per camera ray on the steps of that ray is in :mod:`.integrator`.
The ``scalar_rgb`` post-process keeps the unshadowed haze.

The same formulas in numpy (:func:`transmittance_np`, :func:`source_np`) serve
the ``scalar_rgb`` renderer's post-process, so both renderers share one model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from .arrays import opaque

if TYPE_CHECKING:
    from .emitters import SunTerm

#: |x| below which φ(x) = (1 − e^(−x))/x is evaluated by its Taylor series (float32 cancellation).
SERIES_BELOW = 1e-3
#: Largest −x passed to exp in φ (beyond it the segment is opaque anyway).
MAX_NEG_EXPONENT = 60.0
#: −ln(0.02): Koschmieder's constant (a 2 % contrast threshold), σ₀ = KOSCHMIEDER / V.
KOSCHMIEDER = 3.912
#: Bisections of :meth:`HazeModel.sample_distance`: the scattering point to ℓ / 2¹⁶ (0.3 m on a 20 km sky ray).
SAMPLE_BISECTIONS = 16


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
    #: How far the top rises and falls over the ground, metres (0: a level top).
    variation: float = 0.0
    #: Size of the fog's banks (the noise's wavelength), metres.
    variation_scale: float = 150.0
    seed: int = 0

    def validate(self) -> None:
        """Raise ``ForestError`` unless ρ > 0, F > 0, y_t finite, v ≥ 0 and S > 0."""
        from ...errors import ForestError

        if not (math.isfinite(self.variation) and self.variation >= 0.0):
            raise ForestError(f"path inputs: valley fog variation must be >= 0, got {self.variation}")
        if not (math.isfinite(self.variation_scale) and self.variation_scale > 0.0):
            raise ForestError(f"path inputs: valley fog variation_scale must be > 0, got {self.variation_scale}")

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
    #: forest_path: the sun's share of the in-scattering on camera rays is shadowed (light shafts; see
    #: :mod:`.integrator`, "Light shafts"); off, every point of the haze sees the sun.
    shafts: bool = False

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
    origin_y: npt.ArrayLike,
    direction_y: npt.ArrayLike,
    length: npt.ArrayLike,
    haze: HazeInputs,
    anchor_xz: npt.ArrayLike | None = None,
) -> np.ndarray:
    """T(ℓ) of segments starting at height ``origin_y`` with unit-direction y component ``direction_y``;
    ``anchor_xz`` (…, 2): where each segment reads the fog's top (:func:`fog_anchor_np`; needed only for a
    fog with ``variation``)."""
    oy = np.asarray(origin_y, np.float64)
    sigma = haze.density * np.exp(-(oy - haze.ground) / haze.height)
    ell = np.asarray(length, np.float64)
    tau = sigma * ell * phi_np(ell * np.asarray(direction_y, np.float64) / haze.height)
    if haze.fog is not None:
        tau = tau + fog_depth_np(oy, direction_y, ell, haze.fog, anchor_xz)
    return np.exp(-tau)


def _hash_np(ix: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """The numpy twin of :func:`.clouds._hash`: a float in [0, 1) per lattice point, the same bits."""
    u = np.uint32
    with np.errstate(over="ignore"):
        h = (ix.astype(np.int32).view(u) * u(0x8DA6B343)) ^ (iz.astype(np.int32).view(u) * u(0xD8163841))
        h = h ^ u((seed * 0x9E3779B9) & 0xFFFFFFFF)
        h = (h ^ (h >> u(16))) * u(0x7FEB352D)
        h = (h ^ (h >> u(15))) * u(0x846CA68B)
        h = h ^ (h >> u(16))
    return (h >> u(8)).astype(np.float64) * (1.0 / 16777216.0)


def _value_noise_np(x: np.ndarray, z: np.ndarray, seed: int) -> np.ndarray:
    """The numpy twin of :func:`.clouds.value_noise` (float64 blending)."""
    fx, fz = np.floor(x), np.floor(z)
    ix, iz = fx.astype(np.int64), fz.astype(np.int64)
    tx, tz = x - fx, z - fz
    ux = tx * tx * tx * (tx * (tx * 6.0 - 15.0) + 10.0)
    uz = tz * tz * tz * (tz * (tz * 6.0 - 15.0) + 10.0)
    a, b = _hash_np(ix, iz, seed), _hash_np(ix + 1, iz, seed)
    c, d = _hash_np(ix, iz + 1, seed), _hash_np(ix + 1, iz + 1, seed)
    top = a + (b - a) * ux
    return top + ((c + (d - c) * ux) - top) * uz


#: The fog top's noise: octaves, the second at 2.13× the first's frequency and 0.4 of its weight.
FOG_OCTAVES = ((1.0, 1.0), (2.13, 0.4))


def fog_noise_np(fog: FogLayer, x: npt.ArrayLike, z: npt.ArrayLike) -> np.ndarray:
    """N(x/S, z/S) ∈ [0, 1) of the fog's top at world points (x, z) (module docstring)."""
    x = np.asarray(x, np.float64) / fog.variation_scale
    z = np.asarray(z, np.float64) / fog.variation_scale
    total = np.zeros(np.broadcast_shapes(x.shape, z.shape))
    for i, (f, w) in enumerate(FOG_OCTAVES):
        total += w * _value_noise_np(x * f + 7.1 * i, z * f - 3.3 * i, fog.seed + 101 * i)
    return total / sum(w for _, w in FOG_OCTAVES)


def fog_anchor_np(origin: npt.ArrayLike, direction: npt.ArrayLike, length: npt.ArrayLike) -> np.ndarray:
    """(…, 2) the (x, z) of each segment's lowest end: its end point going down, its start otherwise."""
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    ell = np.asarray(length, np.float64)
    s = np.where(d[..., 1] < 0.0, ell, 0.0)
    return np.stack([o[..., 0] + s * d[..., 0], o[..., 2] + s * d[..., 2]], axis=-1)


def fog_top_np(fog: FogLayer, anchor_xz: npt.ArrayLike | None) -> np.ndarray | float:
    """y_t over the points ``anchor_xz`` (…, 2): the level top plus v·(2N − 1); the level top without variation."""
    if fog.variation <= 0.0:
        return fog.top
    if anchor_xz is None:
        raise ValueError("a valley fog with variation needs the segments' anchors (fog_anchor_np)")
    a = np.asarray(anchor_xz, np.float64)
    return fog.top + fog.variation * (2.0 * fog_noise_np(fog, a[..., 0], a[..., 1]) - 1.0)


def fog_depth_np(
    origin_y: npt.ArrayLike,
    direction_y: npt.ArrayLike,
    length: npt.ArrayLike,
    fog: FogLayer,
    anchor_xz: npt.ArrayLike | None = None,
) -> np.ndarray:
    """τ_f of the valley fog along segments (module docstring): ρ·(ℓ_b + ℓ_a·e^(−(y_lo − y_t)/F)·φ(ℓ_a|d_y|/F)),
    y_t read over ``anchor_xz`` for a fog with ``variation``."""
    oy = np.asarray(origin_y, np.float64)
    dy = np.asarray(direction_y, np.float64)
    ell = np.asarray(length, np.float64)
    top = fog_top_np(fog, anchor_xz)
    flat = np.abs(dy) < 1e-12
    sc = np.clip((top - oy) / np.where(flat, 1.0, dy), 0.0, ell)  # the crossing of y = y_t, clamped
    below = np.where(flat, np.where(oy < top, ell, 0.0), np.where(dy > 0.0, sc, ell - sc))
    above = ell - below
    y_lo = np.where(flat, oy, oy + sc * dy)  # the lowest point of the part above y_t
    rise = np.maximum(y_lo - top, 0.0) / fog.falloff
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
        self.shafts = bool(haze.shafts) and sun is not None

    @staticmethod
    def initial_params(mi: Any, haze: HazeInputs) -> dict[str, Any]:
        """The haze's scene parameters (:attr:`PARAMS`) at ``haze``'s values, as drjit scalars (no colour: black)."""
        return {
            "haze_density": opaque(mi.Float, haze.density),
            "haze_height": opaque(mi.Float, haze.height),
            "haze_colour": opaque(mi.Color3f, *(haze.colour or (0.0, 0.0, 0.0))),
            "haze_anisotropy": opaque(mi.Float, haze.anisotropy),
        }

    def optical_depth(self, o: Any, d: Any, length: Any, top: Any = None) -> Any:
        """τ(ℓ) of the segments o + s·d, s ∈ [0, ``length``] (Float), the fog's top ``top`` per segment
        (default: :meth:`fog_top` of these segments)."""
        import drjit as dr

        inv_h = dr.rcp(self.height)
        sigma = self.density * dr.exp(-(o.y - self.ground) * inv_h)
        x = length * d.y * inv_h
        small = dr.abs(x) < SERIES_BELOW
        xs = dr.select(small, 1.0, dr.maximum(x, -MAX_NEG_EXPONENT))
        phi = dr.select(small, 1.0 - x * 0.5 + x * x * (1.0 / 6.0), (1.0 - dr.exp(-xs)) / xs)
        tau = sigma * length * phi
        if self.fog is None:
            return tau
        if top is None:
            top = self.fog_top(o, d, length)
        return tau + self.fog_depth(o.y, d.y, length, top)

    def sample_distance(self, o: Any, d: Any, length: Any, T: Any, u: Any, top: Any = None) -> Any:
        """s* ∈ [0, ``length``] drawn with density σ(s)T(s)/(1 − T(ℓ)) (the module docstring, "Light shafts"):
        τ(s*) = −ln(1 − u(1 − T(ℓ))) solved by :data:`SAMPLE_BISECTIONS` bisections on the closed form, the
        fog's top held at the whole segment's (the medium the segment's T was computed in; ``top``: that top,
        when the caller has it)."""
        import drjit as dr

        if top is None and self.fog is not None:
            top = self.fog_top(o, d, length)
        target = -dr.log(dr.maximum(1.0 - u * (1.0 - T), 1e-30))
        lo, hi = length * 0.0, length
        for _ in range(SAMPLE_BISECTIONS):
            mid = 0.5 * (lo + hi)
            below = self.optical_depth(o, d, mid, top) < target
            lo, hi = dr.select(below, mid, lo), dr.select(below, hi, mid)
        return 0.5 * (lo + hi)

    def ambient(self) -> Any:
        """C (Color3f): the part of J that does not depend on the sun."""
        return self.mi.Color3f(self.colour)

    def sun_source(self, d: Any) -> Any:
        """E_sun · p_HG(d · s; g) (Color3f): the sun's part of J(d); zero without a sun."""
        import drjit as dr

        mi = self.mi
        if self.sun is None:
            return mi.Color3f(0.0)
        direction, irradiance_of, scale = self.sun
        mu = dr.dot(d, mi.Vector3f(*[float(v) for v in direction]))
        g = self.g
        denom = 1.0 + g * g - 2.0 * g * mu
        p = (1.0 - g * g) * dr.rcp(4.0 * dr.pi * denom * dr.sqrt(denom))
        return irradiance_of(scale) * p

    def sun_direction(self) -> Any:
        """The unit vector toward the sun (Vector3f), or None without a sun."""
        if self.sun is None:
            return None
        return self.mi.Vector3f(*[float(v) for v in self.sun[0]])

    def sun_ray(self, u: Any) -> Any:
        """A direction toward the sun's disc (angular diameter :data:`.inputs.SUN_ANGULAR_DIAMETER`), uniform in
        its cone for ``u`` ∈ [0, 1)²: cos θ = 1 − u₀(1 − cos α), φ = 2π u₁ about the sun's direction."""
        import drjit as dr

        from .inputs import SUN_ANGULAR_DIAMETER

        mi = self.mi
        cos_a = math.cos(math.radians(SUN_ANGULAR_DIAMETER) / 2.0)
        cos_t = 1.0 - u.x * (1.0 - cos_a)
        sin_t = dr.safe_sqrt(1.0 - cos_t * cos_t)
        sin_p, cos_p = dr.sincos(2.0 * dr.pi * u.y)
        local = mi.Vector3f(sin_t * cos_p, sin_t * sin_p, cos_t)
        return mi.Frame3f(self.sun_direction()).to_world(local)

    def transmittance(self, o: Any, d: Any, length: Any) -> Any:
        """T(ℓ) = e^(−τ(ℓ)) of the segments o + s·d, s ∈ [0, ``length``] (Float; :meth:`optical_depth`)."""
        import drjit as dr

        return dr.exp(-self.optical_depth(o, d, length))

    def fog_top(self, o: Any, d: Any, length: Any) -> Any:
        """y_t over each segment's lowest end (the drjit twin of :func:`fog_top_np` at :func:`fog_anchor_np`);
        the level top (a Python float) for a fog without variation."""
        import drjit as dr

        from .clouds import value_noise

        fog = self.fog
        assert fog is not None
        if fog.variation <= 0.0:
            return fog.top
        s = dr.select(d.y < 0.0, length, 0.0)
        inv = 1.0 / fog.variation_scale
        x, z = dr.fma(d.x, s, o.x) * inv, dr.fma(d.z, s, o.z) * inv
        total: Any = 0.0
        for i, (f, w) in enumerate(FOG_OCTAVES):
            total = total + w * value_noise(self.mi, x * f + 7.1 * i, z * f - 3.3 * i, fog.seed + 101 * i)
        n = total * (1.0 / sum(w for _, w in FOG_OCTAVES))
        return fog.top + fog.variation * (2.0 * n - 1.0)

    def fog_depth(self, oy: Any, dy: Any, length: Any, top: Any = None) -> Any:
        """τ_f of the valley fog along the segments (the drjit twin of :func:`fog_depth_np`); ``top``: y_t per
        segment (:meth:`fog_top`; default the level top)."""
        import drjit as dr

        fog = self.fog
        assert fog is not None
        if top is None:
            top = fog.top
        flat = dr.abs(dy) < 1e-12
        sc = dr.clip((top - oy) / dr.select(flat, 1.0, dy), 0.0, length)
        below = dr.select(flat, dr.select(oy < top, length, 0.0), dr.select(dy > 0.0, sc, length - sc))
        above = length - below
        y_lo = dr.select(flat, oy, oy + sc * dy)
        rise = dr.maximum(y_lo - top, 0.0) * (1.0 / fog.falloff)
        x = above * dr.abs(dy) * (1.0 / fog.falloff)
        small = x < SERIES_BELOW
        xs = dr.select(small, 1.0, x)
        phi = dr.select(small, 1.0 - x * 0.5 + x * x * (1.0 / 6.0), (1.0 - dr.exp(-xs)) / xs)
        return fog.density * (below + above * dr.exp(-rise) * phi)

    def source(self, d: Any) -> Any:
        """J(d) (Color3f): the ambient colour plus the sun through the Henyey–Greenstein phase function."""
        if self.sun is None:
            return self.ambient()
        return self.ambient() + self.sun_source(d)
