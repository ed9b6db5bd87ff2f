"""Sun and sky for the forest path tracer: sampling, evaluation and the MIS densities.

Every light is *at infinity*: it is a radiance function of direction L(ω) =
s · ℓ(ω) where s is an RGB scale read from the scene parameters at render time
(a drjit ``Color3f`` the caller may differentiate or change between passes
without rebuilding anything) and ℓ a fixed shape:

* :class:`DiscSun` — uniform over a cone of half-angle α around the sun
  direction: ℓ = 1/(π sin²α) inside, so ∫ ℓ cos θ dω = π sin²α · ℓ = 1 for a surface facing
  the sun and s is the irradiance E; sampled uniformly in the cone,
  pdf = 1/(2π(1 − cos α)) (``mi.warp.square_to_uniform_cone``).
* :class:`ConstantSky` — ℓ = 1, s the radiance; sampled cosine-weighted over the upper hemisphere.
* :class:`SkyBasis` — one half of the ``gradient`` sky, L = s_z·(1 − b) + s_h·b with
  b = (1 − μ)^k, μ = max(ω_y, 0): ℓ = 1 − b (the zenith's share, parameter
  ``sky_zenith``) or ℓ = b (the horizon's, ``sky_horizon``); k = 1 is linear in μ,
  a larger k a glow band along the horizon; sampled like the constant sky.
* :class:`EmitterLight` — a Mitsuba ``envmap`` or ``sunsky`` (sky only, or its
  sun only) with ``scale`` 1, importance-sampled by Mitsuba itself (native calls
  on one emitter object: no virtual dispatch over the scene).  ``sunsky`` is
  Z-up in Mitsuba 3.9.1; its ``to_world`` here maps local +Z to world +Y (and
  local +Y to world −Z), and its ``sun_direction`` is given in world space.
  A ``sunsky`` may be *normalised* (:attr:`SkyLight.sun_irradiance`): sun and
  sky are scaled by one factor k so that the model's sun sends
  ``sun_irradiance`` (luminance, W/m² facing the sun) — the meaning
  ``[lights.sun] irradiance`` has with the disc sun — keeping the model's
  colours and its sun-to-sky ratio (:func:`sunsky_scale`).

Next-event estimation picks light k with probability P_k (proportional to an
estimate of the power it sends onto an upward surface at its initial scale,
each kept ≥ :data:`MIN_PICK`), so the light-sampling density of a direction is
p_L(ω) = Σ_k P_k p_k(ω), the density the power heuristic of Veach (1997,
§9.2.4) weighs against the BSDF's.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

from ...runtime import load_scene_dict
from .arrays import mappable, opaque
from .inputs import SkyLight, SunLight

#: Smallest probability of picking a light for next-event estimation when there are two.
MIN_PICK = 0.2
#: Directions over the upper hemisphere used to estimate a sky's mean radiance.
SKY_PROBES = 512
#: Stratified samples used to measure a sunsky sun's irradiance.
SUN_SAMPLES = 1024
#: Elevation (degrees) below which a normalised sunsky takes its scale from a sun at this elevation.
MIN_NORMALISE_ELEVATION = 2.0

#: Local (Mitsuba sunsky, Z up) → world (Y up): x → x, y → −z, z → y.
#: A sun as the haze sees it (:meth:`LightSet.sun`): (direction toward it, scale → RGB irradiance, its scale).
SunTerm = tuple[tuple[float, ...], Callable[[Any], Any], Any]

Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def luminance(rgb: npt.ArrayLike) -> float:
    """Rec. 709 luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of the first three values of ``rgb``."""
    r, g, b = (float(x) for x in np.asarray(rgb, dtype=np.float64).ravel()[:3])
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def fibonacci_hemisphere(n: int) -> np.ndarray:
    """(n, 3) directions spread evenly over the upper (+Y) hemisphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    y = 1.0 - i / n
    r = np.sqrt(np.maximum(0.0, 1.0 - y * y))
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)


class DiscSun:
    """A sun of finite angular radius α; its parameter is the irradiance E (RGB)."""

    param = "sun_irradiance"

    def __init__(self, mi: Any, sun: SunLight):
        d = np.asarray(sun.direction, dtype=np.float64)
        self.direction = d / np.linalg.norm(d)
        alpha = math.radians(float(sun.angular_diameter)) / 2.0
        # The cone as float32 samples it: its rim, solid angle and density all use this cos α.
        self.cos_alpha = float(np.float32(math.cos(alpha)))
        one_minus = 1.0 - self.cos_alpha
        self.radiance_per_irradiance = 1.0 / (math.pi * one_minus * (1.0 + self.cos_alpha))
        self.inv_solid_angle = 1.0 / (2.0 * math.pi * one_minus)
        # Inside test on the chord, |d − s|² = 2(1 − cos θ) ≤ 2(1 − cos α): well conditioned in
        # float32 where 1 − cos θ itself is not; the margin covers the rounding of sampled directions.
        self.chord2 = 2.0 * one_minus * (1.0 + 1e-3)
        self.initial = np.asarray(sun.irradiance, dtype=np.float64)
        self.mi = mi

    def power(self, scale: npt.ArrayLike) -> float:
        """Pick weight for next-event estimation: luminance of E times the sun's elevation sine (at least 0.05)."""
        return luminance(scale) * max(self.direction[1], 0.05)

    def irradiance(self, scale: Any) -> Any:
        """RGB irradiance facing the sun: the scale itself."""
        return self.mi.Color3f(scale)

    def _frame(self) -> Any:
        mi = self.mi
        return mi.Frame3f(mi.Vector3f(*[float(x) for x in self.direction]))

    def sample(self, scale: Any, u: Any, active: Any) -> tuple[Any, Any, Any]:  # noqa: ARG002 (every light has this signature)
        """A direction uniform in the sun's cone: (d, pdf = 1/(2π(1 − cos α)), radiance s·ℓ)."""
        import drjit as dr

        mi = self.mi
        local = mi.warp.square_to_uniform_cone(u, self.cos_alpha)
        d = self._frame().to_world(local)
        pdf = dr.full(mi.Float, self.inv_solid_angle, dr.width(u))
        return d, pdf, scale * self.radiance_per_irradiance

    def inside(self, d: Any) -> Any:
        """Whether unit direction ``d`` lies in the sun's cone, tested on the chord: |d − s|² ≤ 2(1 − cos α)."""
        import drjit as dr

        s = self.direction
        dx, dy, dz = d.x - float(s[0]), d.y - float(s[1]), d.z - float(s[2])
        return dr.fma(dx, dx, dr.fma(dy, dy, dz * dz)) <= self.chord2

    def eval(self, scale: Any, d: Any, active: Any) -> Any:
        """Radiance toward ``d``: E/(π sin²α) inside the cone, else 0."""
        import drjit as dr

        return dr.select(active & self.inside(d), scale * self.radiance_per_irradiance, 0.0)

    def pdf(self, d: Any, active: Any) -> Any:
        """Solid-angle density of :meth:`sample` at ``d``: 1/(2π(1 − cos α)) inside the cone, else 0."""
        import drjit as dr

        return dr.select(active & self.inside(d), self.inv_solid_angle, 0.0)


class ConstantSky:
    """Radiance s in every direction; light samples are drawn over the upper hemisphere only.

    Sampling density p(ω) = max(ω_y, 0)/π (cosine-weighted about +Y): outdoors,
    light from below the horizon is blocked by the ground, so samples there
    would cost a shadow ray for nothing.  Directions below the horizon are still
    reached by BSDF sampling, whose MIS weight is 1 where p = 0, so the estimate
    stays unbiased.
    """

    param = "sky_radiance"

    def __init__(self, mi: Any, sky: SkyLight):
        self.mi = mi
        self.initial = np.asarray(sky.radiance, dtype=np.float64)
        self.mean_radiance = np.ones(3)  # times the scale: the radiance itself

    def power(self, scale: npt.ArrayLike) -> float:
        """Pick weight for next-event estimation: luminance of the irradiance π·s on an upward plane."""
        return math.pi * luminance(scale)

    def sample(self, scale: Any, u: Any, active: Any) -> tuple[Any, Any, Any]:  # noqa: ARG002 (every light has this signature)
        """A cosine-weighted direction about +Y: (d, pdf = max(d_y, 0)/π, radiance s)."""
        import drjit as dr

        mi = self.mi
        local = mi.warp.square_to_cosine_hemisphere(u)
        d = mi.Vector3f(local.x, local.z, -local.y)  # local +Z → world +Y
        return d, dr.maximum(d.y, 0.0) * dr.inv_pi, mi.Color3f(scale)

    def eval(self, scale: Any, d: Any, active: Any) -> Any:  # noqa: ARG002 (every light has this signature)
        """Radiance s, the same toward every direction (0 where not ``active``)."""
        import drjit as dr

        return dr.select(active, scale, 0.0)

    def pdf(self, d: Any, active: Any) -> Any:
        """Solid-angle density of :meth:`sample` at ``d``: max(d_y, 0)/π."""
        import drjit as dr

        return dr.select(active, dr.maximum(d.y, 0.0) * dr.inv_pi, 0.0)


class SkyBasis(ConstantSky):
    """One basis function of the ``gradient`` sky: ℓ(ω) = 1 − b (zenith) or b (horizon), b = (1 − μ)^k.

    μ = max(ω_y, 0) and k ≥ 1 the horizon band's exponent (1: L linear in μ; a
    larger k narrows the horizon's colour to a band of height about 1/k in μ).
    On an upward plane the horizon's share delivers ∫ b cos θ dω = 2π∫(1 − μ)^k μ dμ =
    a_k = 2π/((k + 1)(k + 2)) and the zenith's π − a_k per unit scale (k = 1: π/3
    and 2π/3).  Sampled cosine-weighted over the upper hemisphere like
    :class:`ConstantSky` (below the horizon only the horizon term is non-zero,
    reached by BSDF sampling).
    """

    def __init__(self, mi: Any, param: str, initial: npt.ArrayLike, zenith: bool, exponent: float = 1.0):
        self.mi = mi
        self.param = param
        self.zenith = bool(zenith)
        self.initial = np.asarray(initial, dtype=np.float64)
        self.set_exponent(exponent)

    def set_exponent(self, exponent: float) -> None:
        """The band's exponent k, and with it the mean of ℓ over the upper hemisphere (solid angle):
        ∫₀¹ (1 − μ)^k dμ = 1/(k + 1) for the horizon's.  A kernel traced afterwards uses the new shape."""
        self.exponent = float(exponent)
        self._k = opaque(self.mi.Float, self.exponent)  # a kernel parameter: a fitted k compiles no new kernel
        h = 1.0 / (self.exponent + 1.0)
        self.mean_radiance = np.full(3, 1.0 - h if self.zenith else h)

    def power(self, scale: npt.ArrayLike) -> float:
        """Pick weight: luminance of s times ℓ's irradiance on an upward plane (zenith π − a_k, horizon a_k)."""
        a = horizon_irradiance(self.exponent)
        return luminance(scale) * (math.pi - a if self.zenith else a)

    def _shape(self, d: Any) -> Any:
        import drjit as dr

        mu = dr.maximum(d.y, 0.0)
        band = 1.0 - mu if self.exponent == 1.0 else dr.power(1.0 - mu, self._k)
        return 1.0 - band if self.zenith else band

    def sample(self, scale: Any, u: Any, active: Any) -> tuple[Any, Any, Any]:
        """As :meth:`ConstantSky.sample`, with radiance s·ℓ(d)."""
        d, pdf, _ = super().sample(scale, u, active)
        return d, pdf, scale * self._shape(d)

    def eval(self, scale: Any, d: Any, active: Any) -> Any:
        """Radiance s·ℓ(d) toward ``d``."""
        import drjit as dr

        return dr.select(active, scale * self._shape(d), 0.0)


def horizon_irradiance(exponent: float) -> float:
    """a_k = 2π/((k + 1)(k + 2)): the irradiance on an upward plane from a unit-scale horizon band (1 − μ)^k."""
    k = float(exponent)
    return 2.0 * math.pi / ((k + 1.0) * (k + 2.0))


def gradient_radiance(
    zenith: npt.ArrayLike, horizon: npt.ArrayLike, mu: npt.ArrayLike, exponent: float = 1.0
) -> np.ndarray:
    """The ``gradient`` sky's radiance at μ = max(ω_y, 0) (numpy; ``mu`` broadcasts against the colours)."""
    b = (1.0 - np.clip(np.asarray(mu, np.float64), 0.0, 1.0)) ** float(exponent)
    return np.asarray(zenith, np.float64) * (1.0 - b) + np.asarray(horizon, np.float64) * b


def sun_irradiance_of(mi: Any, emitter: Any, direction: npt.ArrayLike, samples: int = SUN_SAMPLES) -> np.ndarray:
    """RGB irradiance E⊥ = ∫ L(ω) (ω · s) dω that a sun-like emitter sends onto a plane facing ``direction`` s.

    Estimated from ``samples`` of the emitter's own direction sampling (weights L/pdf), on a
    fixed stratified grid so the value is deterministic.  Works in every variant.
    """
    import drjit as dr

    s = np.asarray(direction, np.float64)
    s = s / np.linalg.norm(s)
    k = int(math.isqrt(samples))
    g = (np.arange(k) + 0.5) / k
    u1, u2 = (a.ravel() for a in np.meshgrid(g, g))
    if mi.variant().startswith("scalar"):
        total = np.zeros(3)
        it = dr.zeros(mi.Interaction3f)
        for a, b in zip(u1.tolist(), u2.tolist()):
            ds, w = emitter.sample_direction(it, mi.Point2f(a, b))
            if ds.pdf > 0:
                total += np.asarray([w[0], w[1], w[2]], np.float64) * max(float(dr.dot(ds.d, mi.Vector3f(*s))), 0.0)
        return total / len(u1)
    with dr.suspend_grad():
        it = dr.zeros(mi.Interaction3f, len(u1))
        u = mi.Point2f(mi.Float(mappable(u1.astype(np.float32))), mi.Float(mappable(u2.astype(np.float32))))
        ds, w = emitter.sample_direction(it, u, mi.Bool(True))
        cos = dr.maximum(dr.dot(ds.d, mi.Vector3f(*[float(v) for v in s])), 0.0)
        ok = ds.pdf > 0.0
        e = [np.asarray(dr.select(ok, w[c] * cos, 0.0), np.float64).sum() for c in range(3)]
    return np.asarray(e) / len(u1)


def sunsky_dict(
    mi: Any, direction: npt.ArrayLike, turbidity: float, albedo: float, *, sun_scale: float, sky_scale: float
) -> dict[str, Any]:
    """Mitsuba's ``sunsky`` rotated to Y-up (``to_world`` local +Z → world +Y), sun toward ``direction`` (world)."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    return {
        "type": "sunsky",
        "sun_direction": [float(x) for x in d],
        "turbidity": float(turbidity),
        "albedo": float(albedo),
        "to_world": mi.ScalarTransform4f(Z_UP_TO_Y_UP),
        "sun_scale": float(sun_scale),
        "sky_scale": float(sky_scale),
    }


def sunsky_scale(mi: Any, direction: npt.ArrayLike, turbidity: float, albedo: float, sun_irradiance: float) -> float:
    """The factor k that makes the ``sunsky`` sun toward ``direction`` send ``sun_irradiance`` (luminance, facing it).

    Below :data:`MIN_NORMALISE_ELEVATION` degrees the model's sun fades to nothing; k is then taken at that
    elevation (same azimuth), so a sun at the horizon gives a dim, finite sky rather than a division by zero.
    """
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    floor = math.sin(math.radians(MIN_NORMALISE_ELEVATION))
    if d[1] < floor:
        h = math.hypot(d[0], d[2]) or 1.0
        c = math.sqrt(1.0 - floor * floor)
        d = np.array([d[0] / h * c if h else c, floor, d[2] / h * c if h else 0.0])
    key = (mi.variant(), tuple(np.round(d, 7)), round(float(turbidity), 7), round(float(albedo), 7))
    if key not in _SUN_UNIT:
        em = mi.load_dict(sunsky_dict(mi, d, turbidity, albedo, sun_scale=1.0, sky_scale=0.0))
        _SUN_UNIT[key] = luminance(sun_irradiance_of(mi, em, d))
    unit = _SUN_UNIT[key]
    return float(sun_irradiance) / unit if unit > 0 else 0.0


_SUN_UNIT: dict[tuple[Any, ...], float] = {}


class EmitterLight:
    """A Mitsuba environment emitter (``envmap`` or ``sunsky``) at unit scale, times s.

    ``sun``: the emitter is a sun (``sunsky`` with its sky off) toward ``direction``: its power and
    the haze's sun term use its irradiance :attr:`unit_irradiance`, estimated by sampling (the
    hemisphere probes would miss a half-degree disc).
    """

    def __init__(
        self, mi: Any, emitter: Any, param: str, initial: npt.ArrayLike, *, direction: npt.ArrayLike | None = None
    ):
        import drjit as dr

        self.mi = mi
        self.emitter = emitter
        # Infinite emitters sample directions from their scene's bounding sphere: give them one.
        self._holder = load_scene_dict(mi, {"type": "scene", "light": emitter})
        self.param = param
        self.initial = np.asarray(initial, dtype=np.float64)
        self.direction = None if direction is None else np.asarray(direction, np.float64) / np.linalg.norm(direction)
        probes = fibonacci_hemisphere(SKY_PROBES)
        d = mi.Vector3f(*[mi.Float(mappable(probes[:, k].astype(np.float32))) for k in range(3)])
        with dr.suspend_grad():
            # A Color3f of N lanes is (3, N) as an array: one row per probe after the transpose (a plain
            # reshape to (N, 3) would mix the channels of neighbouring probes into grey).
            value = np.asarray(self._eval_unit(d, mi.Bool(True)), dtype=np.float64).reshape(3, -1).T
        # E on an upward plane ≈ 2π · mean(ℓ cos θ) over the hemisphere (uniform probes).
        self.unit_irradiance_up = (2.0 * math.pi * value * probes[:, 1:2]).mean(axis=0)
        self.unit_power = luminance(self.unit_irradiance_up)
        #: Mean radiance over the upper hemisphere (RGB, unit scale): the default haze colour of a sky.
        self.mean_radiance = value.mean(axis=0)
        self.peak = float(value.max()) if value.size else 0.0
        self.unit_irradiance = np.zeros(3)
        if self.direction is not None:
            self.unit_irradiance = sun_irradiance_of(mi, emitter, self.direction)
            self.unit_power = luminance(self.unit_irradiance) * max(float(self.direction[1]), 0.05)

    def power(self, scale: npt.ArrayLike) -> float:
        """Pick weight: luminance of s times :attr:`unit_power` (a sun's: E facing it times its elevation sine)."""
        return luminance(scale) * self.unit_power

    def irradiance(self, scale: Any) -> Any:
        """The sun's RGB irradiance facing it at scale ``scale`` (a Color3f that may carry gradients)."""
        mi = self.mi
        return scale * mi.Color3f(*[float(v) for v in self.unit_irradiance])

    def _eval_unit(self, d: Any, active: Any) -> Any:
        import drjit as dr

        mi = self.mi
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
        si.wi = -d
        return self.emitter.eval(si, active)

    def sample(self, scale: Any, u: Any, active: Any) -> tuple[Any, Any, Any]:
        """Mitsuba's importance sampling of the emitter: (d, pdf, radiance s·ℓ(d)), 0 where it fails."""
        import drjit as dr

        mi = self.mi
        it = dr.zeros(mi.Interaction3f, dr.width(u))
        ds, w = self.emitter.sample_direction(it, u, active)
        ok = active & (ds.pdf > 0.0)
        return ds.d, dr.select(ok, ds.pdf, 0.0), dr.select(ok, scale * w * ds.pdf, 0.0)

    def eval(self, scale: Any, d: Any, active: Any) -> Any:
        """Radiance s·ℓ(d) of the emitter toward ``d``."""
        import drjit as dr

        return dr.select(active, scale * self._eval_unit(d, active), 0.0)

    def pdf(self, d: Any, active: Any) -> Any:
        """Mitsuba's solid-angle density of sampling direction ``d`` (:meth:`sample`)."""
        import drjit as dr

        mi = self.mi
        it = dr.zeros(mi.Interaction3f, dr.width(d))
        ds = dr.zeros(mi.DirectionSample3f, dr.width(d))
        ds.d = d
        return dr.select(active, self.emitter.pdf_direction(it, ds, active), 0.0)


class CloudedLights(list):  # type: ignore[type-arg]
    """The light objects of a sky with a cloud layer: a list of lights that also carries :attr:`clouds`
    (a :class:`~.clouds.CloudLayer`), which :class:`LightSet` lays over their radiance."""

    clouds: Any = None


def make_lights(mi: Any, sun: SunLight | None, sky: SkyLight | None) -> list[Any]:
    """The light objects for a sun and sky description (see the module docstring).

    A sky with clouds (:attr:`SkyLight.clouds`) gives a :class:`CloudedLights`; without, a plain list.
    """
    lights = _make_lights(mi, sun, sky)
    clouds = getattr(sky, "clouds", None) if sky is not None else None
    if clouds is None or float(clouds.cover) <= 0.0:
        return lights
    from .clouds import CloudLayer

    out = CloudedLights(lights)
    out.clouds = CloudLayer(mi, clouds)
    return out


def _make_lights(mi: Any, sun: SunLight | None, sky: SkyLight | None) -> list[Any]:
    lights: list[Any] = []
    if sky is not None and sky.kind == "sunsky":
        assert sun is not None
        d = np.asarray(sun.direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        k = 1.0
        if sky.sun_irradiance is not None:
            k = sunsky_scale(mi, d, sky.turbidity, sky.albedo, sky.sun_irradiance)
        if d[1] > 0.0:
            sun_em = mi.load_dict(sunsky_dict(mi, d, sky.turbidity, sky.albedo, sun_scale=1.0, sky_scale=0.0))
            lights.append(EmitterLight(mi, sun_em, "sun_scale", [k * sky.sun_scale] * 3, direction=d))
        sky_em = mi.load_dict(sunsky_dict(mi, d, sky.turbidity, sky.albedo, sun_scale=0.0, sky_scale=1.0))
        lights.append(EmitterLight(mi, sky_em, "sky_scale", [k * sky.scale] * 3))
        return lights
    if sun is not None and float(np.asarray(sun.direction, dtype=np.float64)[1]) > -1.0:
        lights.append(DiscSun(mi, sun))
    if sky is not None:
        if sky.kind == "gradient":
            lights.append(SkyBasis(mi, "sky_zenith", sky.zenith, True, sky.horizon_exponent))
            lights.append(SkyBasis(mi, "sky_horizon", sky.horizon, False, sky.horizon_exponent))
        elif sky.kind == "envmap":
            em = mi.load_dict({"type": "envmap", "filename": str(sky.envmap), "scale": 1.0})
            lights.append(EmitterLight(mi, em, "sky_scale", [sky.scale] * 3))
        else:
            lights.append(ConstantSky(mi, sky))
    return lights


#: Turbidity and ground albedo of the sky model a backdrop shows (:class:`Backdrop`): a clear day.
BACKDROP_TURBIDITY = 3.0
BACKDROP_ALBEDO = 0.15


class Backdrop:
    """What camera rays that leave the scene see in place of an environment map (``[lights.sky] background =
    "sunsky"``): Mitsuba's sky model without its sun (forest's disc sun still draws the sun) for the
    direction ``s`` of the scene's sun, times k so that its mean radiance over the upper hemisphere has the
    map's luminance,

        L_b(ω) = k · ℓ_model(ω; s),    k = Y(ℓ̄_map) / Y(ℓ̄_model),

    ℓ̄ the means over uniform hemisphere probes and Y the Rec. 709 luminance.  Only what the camera sees
    changes: every bounce and shadow ray is still lit by the map.  A constant (it carries no gradients):
    look-dev fits the lights, not the backdrop.
    """

    def __init__(self, mi: Any, direction: npt.ArrayLike, map_mean: npt.ArrayLike):
        d = np.asarray(direction, np.float64)
        d = d / np.linalg.norm(d)
        if d[1] < 0.02:  # the model needs a sun above the horizon: keep its azimuth, raise it a little
            d = np.array([d[0], 0.02, d[2]]) / np.linalg.norm([d[0], 0.02, d[2]])
        em = mi.load_dict(sunsky_dict(mi, d, BACKDROP_TURBIDITY, BACKDROP_ALBEDO, sun_scale=0.0, sky_scale=1.0))
        self.mi = mi
        self.light = EmitterLight(mi, em, "sky_scale", [1.0, 1.0, 1.0])
        model = luminance(self.light.mean_radiance)
        self.k = luminance(map_mean) / model if model > 0.0 else 0.0

    def eval(self, d: Any, active: Any) -> Any:
        """L_b(d) (RGB)."""
        return self.light.eval(self.mi.Color3f(self.k), d, active)


def make_backdrop(mi: Any, sun: SunLight | None, sky: SkyLight | None, lights: list[Any]) -> Backdrop | None:
    """The :class:`Backdrop` of an ``envmap`` sky with ``background = "sunsky"`` (None otherwise); the sun's
    direction from ``sun`` (the map's found sun or [lights.sun]), straight up without one."""
    if sky is None or sky.kind != "envmap" or sky.background != "sunsky":
        return None
    direction = (0.0, 1.0, 0.0) if sun is None else sun.direction
    return Backdrop(mi, direction, sky_mean_radiance(lights))


class LightSet:
    """The lights of a render with their current scales and pick probabilities; ``backdrop`` (a
    :class:`Backdrop` or None) is what camera rays that leave the scene see instead of the sky."""

    def __init__(self, mi: Any, lights: list[Any], params: dict[str, Any], backdrop: Backdrop | None = None):
        self.mi = mi
        self.lights = lights
        self.backdrop = backdrop
        self.scales = [params[light.param] for light in lights]
        # Picks follow the lights' *initial* values: fixed while parameters change (an optimiser's
        # steps, finite differences), so the estimate stays a smooth function of the light scales.
        power = np.array([max(light.power(light.initial), 0.0) for light in lights])
        if len(lights) == 0 or power.sum() <= 0:
            pick = np.full(len(lights), 1.0 / max(len(lights), 1))
        else:
            pick = power / power.sum()
            if len(lights) > 1:
                pick = np.maximum(pick, MIN_PICK)
                pick /= pick.sum()
        self.pick = [float(p) for p in pick]
        #: The cloud layer laid over the lights' radiance (:mod:`.clouds`), or None.
        self.clouds = getattr(lights, "clouds", None)

    def sun(self) -> SunTerm | None:
        """(direction toward the sun, scale → RGB irradiance, current scale) of the sun, or None."""
        for light, s in zip(self.lights, self.scales):
            direction = getattr(light, "direction", None)
            if direction is not None:
                return (tuple(float(v) for v in direction), light.irradiance, s)
        return None

    def _clouded(self, d: Any, active: Any, origin: Any, camera: Any = None, jitter: Any = None) -> tuple[Any, Any]:
        """(sky, sun) radiance toward ``d`` from ``origin`` through the cloud layer (:meth:`.CloudLayer.apply`);
        lanes in ``camera`` (camera rays) see the cumulus in height, marched with ``jitter`` (None: hashed)."""
        mi = self.mi
        sky, sun = mi.Color3f(0.0), mi.Color3f(0.0)
        ambient = mi.Color3f(0.0)
        sun_term = None
        for light, s in zip(self.lights, self.scales):
            value = light.eval(s, d, active)
            direction = getattr(light, "direction", None)
            if direction is None:
                sky += value
                ambient += mi.Color3f(*[float(v) for v in light.mean_radiance]) * s
            else:
                sun += value
                if sun_term is None:
                    sun_term = (mi.Vector3f(*[float(v) for v in direction]), light.irradiance(s))
        o = mi.Point3f(0.0) if origin is None else origin
        assert self.clouds is not None
        return self.clouds.apply(o, d, active, sky, sun, sun_term, ambient, camera, jitter)

    def eval(self, d: Any, active: Any, origin: Any = None, camera: Any = None, jitter: Any = None) -> Any:
        """Radiance arriving from direction ``d`` (a ray that left the scene), all lights summed.

        With a cloud layer the radiance also depends on the ray's ``origin`` (equation (1) of
        :mod:`.clouds`; the world origin when None); without one ``origin`` is not used.  Lanes in
        ``camera`` (camera rays) see the :attr:`backdrop` instead where there is one, else the cumulus,
        marched with ``jitter`` ∈ [0, 1) per lane (the path's own sample; None: hashed from ``d``).
        """
        mi = self.mi
        if self.clouds is not None:
            sky, sun = self._clouded(d, active, origin, camera if self.backdrop is None else None, jitter)
            total = sun + sky
        else:
            total = mi.Color3f(0.0)
            for light, s in zip(self.lights, self.scales):
                total += light.eval(s, d, active)
        if camera is None or self.backdrop is None:
            return total
        import drjit as dr

        return dr.select(camera, self._backdrop(d, camera)[0], total)

    @property
    def groups(self) -> list[str]:
        """The light groups of these lights, in order of first appearance (:func:`light_group`)."""
        return list(dict.fromkeys(light_group(light) for light in self.lights))

    def eval_groups(
        self, d: Any, active: Any, origin: Any = None, camera: Any = None, jitter: Any = None
    ) -> tuple[Any, dict[str, Any]]:
        """:meth:`eval` and its split by light group: (Σ_k L_k(d), {group g: Σ_{k ∈ g} L_k(d)}).

        The total is summed in the same order and with the same operations as :meth:`eval`, so it is
        bit for bit the same value; each light is evaluated once.  With clouds the sun's group takes the
        sun's radiance through the layer and the cloud's sunlit radiance, the sky's the rest.  Lanes in
        ``camera`` see the :attr:`backdrop` (in ``sky``) and the suns (in ``sun``) where there is one.
        """
        mi = self.mi
        parts: dict[str, Any] = {}
        if self.clouds is not None:
            sky, sun = self._clouded(d, active, origin, camera if self.backdrop is None else None, jitter)
            total = sun + sky
            parts = {g: (sun if g == "sun" else sky) for g in self.groups}
        else:
            total = mi.Color3f(0.0)
            for light, s in zip(self.lights, self.scales):
                value = light.eval(s, d, active)
                total += value
                g = light_group(light)
                parts[g] = value if g not in parts else parts[g] + value
        if camera is None or self.backdrop is None:
            return total, parts
        import drjit as dr

        seen, seen_parts = self._backdrop(d, camera)
        return dr.select(camera, seen, total), {g: dr.select(camera, seen_parts[g], parts[g]) for g in parts}

    def _backdrop(self, d: Any, active: Any) -> tuple[Any, dict[str, Any]]:
        """What a camera ray toward ``d`` sees with a :attr:`backdrop`: (L_b(d) + the suns' radiance, split
        by light group: the backdrop in ``sky``, the suns in ``sun``), so the sun's disc stays in the frame."""
        mi = self.mi
        assert self.backdrop is not None
        total = self.backdrop.eval(d, active)
        parts: dict[str, Any] = {"sky": total}
        for light, s in zip(self.lights, self.scales):
            if getattr(light, "direction", None) is not None:
                value = light.eval(s, d, active)
                total = total + value
                parts["sun"] = value if "sun" not in parts else parts["sun"] + value
        return total, {g: parts.get(g, mi.Color3f(0.0)) for g in self.groups}

    def pdf(self, d: Any, active: Any) -> Any:
        """Light-sampling density p_L(d) = Σ P_k p_k(d) (solid angle)."""
        import drjit as dr

        mi = self.mi
        total = dr.zeros(mi.Float, dr.width(d))
        for light, p in zip(self.lights, self.pick):
            total += p * light.pdf(d, active)
        return total

    def sample_direction(self, u_pick: Any, u: Any, active: Any) -> tuple[Any, Any]:
        """Pick light k with probability P_k and sample d ~ p_k: (d, p_L(d)).

        The pick-then-sample mixture is one strategy of density p_L; its
        estimate f·L(d)/p_L(d) takes L summed over all lights (:meth:`eval`),
        which is unbiased where lights overlap (the sun's disc lies inside the
        sky), and p_L is what the BSDF strategy's MIS weight needs.
        """
        import drjit as dr

        mi = self.mi
        if not self.lights:
            return mi.Vector3f(0.0, 1.0, 0.0), dr.zeros(mi.Float, dr.width(u))
        d = mi.Vector3f(0.0, 1.0, 0.0)
        edge = 0.0
        for k, (light, s, p) in enumerate(zip(self.lights, self.scales, self.pick)):
            lo, edge = edge, edge + p
            sel = active & (u_pick >= lo)
            if k + 1 < len(self.lights):
                sel &= u_pick < edge
            dk, _, _ = light.sample(s, u, sel)
            d = dr.select(sel, dk, d)
        return d, self.pdf(d, active)


def light_group(light: Any) -> str:
    """The comp light group a light's contributions are written to: ``sun`` for a sun (a light with a
    ``direction``: :class:`DiscSun`, a ``sunsky``'s sun), ``sky`` for every sky (constant, gradient,
    ``envmap``, a ``sunsky``'s sky).  forest has no other emitters."""
    return "sun" if getattr(light, "direction", None) is not None else "sky"


def sky_mean_radiance(lights: list[Any]) -> np.ndarray:
    """The sky's mean radiance over the upper hemisphere at its initial scale (RGB; 0 without a sky)."""
    total = np.zeros(3)
    for light in lights:
        if getattr(light, "direction", None) is None and hasattr(light, "mean_radiance"):
            total += np.asarray(light.mean_radiance, np.float64) * np.asarray(light.initial, np.float64)
    return total
