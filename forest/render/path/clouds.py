"""A procedural cloud layer in forest_path's sky: cumulus, their silver linings and shadows.

**Geometry.**  The clouds lie on the horizontal plane y = h (``altitude``).  A ray from o along
the unit direction ω (ω_y > 0, o_y < h) crosses it at distance

    t = (h − o_y) / ω_y,      x_c = (o_x + t ω_x,  o_z + t ω_z)                      (1)

so the sky seen from a point depends on where that point is: camera rays see the layer from the
camera, and a shading point's sun ray crosses it above that point — the clouds' shadows move over
the ground as ``wind`` slides the layer.

**Shape.**  An fBm (fractional Brownian motion) of value noise, the sum of 5 octaves
n(x) = Σ_i a^i v(2^i R^i x / S + c_i) / Σ_i a^i with gain a = 0.5, a rotation R between octaves and
S = ``scale`` (Perlin 1985; Perlin 2002, "Improving noise", for the quintic fade
6u⁵ − 15u⁴ + 10u³; Ebert, Musgrave, Peachey, Perlin & Worley, *Texturing & Modeling: A
Procedural Approach*, 3rd ed. 2003, ch. 4 and 16 for fBm clouds).  v is the value noise of a
lattice of integer hashes (a xorshift–multiply mixer), interpolated with the fade: cheap,
deterministic and the same on every device.  The layer covers a fraction ``cover`` of the sky: the
noise is thresholded at its (1 − cover) quantile n₀ (measured once on a 256×256 grid), and

    τ(x) = D · smoothstep(0, w, n(x) − n₀) · (1 + 2 (n(x) − n₀)/(1 − n₀))                 (2)

is the optical thickness (D = ``density``, w = ``softness``: the width of the edge in noise units).

**Groups.**  Fair-weather cumulus are not spread evenly: they gather in groups and fields with clear
sky between, at scales several times a cloud's size (organised convection), so a sky toward the horizon
shows banks and gaps rather than an even band.  With c = ``clustering`` the noise thresholded in (2) is

    n'(x) = n(x) + c · G · (m(x) − ½)                                                        (2')

with m a value noise :data:`CLUSTER` × ``scale`` across (its lattice turned so no axis shows) and
G = :data:`CLUSTER_GAIN`: where m is high a group's clouds merge and grow, where it is low the sky is
clear.  n₀ is measured on n', over a span of :data:`QUANTILE_SPAN` × ``scale`` (dozens of groups), so
the whole sky keeps its ``cover``; a view of a patch smaller than a group sees more or less of it.

**Radiance.**  What a ray sees of the sky through the layer is

    L = T·(L_sky + L_sun) + (1 − T)·L_cloud,     T = exp(−τ f(t))                       (3)

with f(t) = exp(−t / (30 h)) a fade with distance: toward the horizon the layer thins into the haze
(and its aliasing with it).  The cloud's own radiance is single-scattered sunlight plus ambient:

    L_cloud = E_sun [ p_HG(ω·s; g) e^(−τ/2) + (ρ/π) e^(−τ_s) / (1 + τ/4) ] + k_a · L̄_sky         (4)

E_sun the sun's irradiance facing it (RGB), s the unit vector toward it, p_HG the Henyey–Greenstein
phase function (Henyey & Greenstein 1941) with g = 0.6: the forward peak through the thin edges of a
cloud next to the sun is its silver lining, and e^(−τ/2) closes it in a thick core.  The second term
is the sunlit cloud seen from below, with albedo ρ = 0.9, darkened by the cloud's own depth through
1/(1 + τ/4) and by a cheap self-shadow e^(−τ_s), τ_s = τ(x_c + (H/s_y)·s_xz) the thickness found by
stepping once toward the sun by the layer's thickness H = scale/4 (Schneider & Vos 2015, "The
real-time volumetric cloudscapes of Horizon Zero Dawn", for beer-law self-shadowing).
L̄_sky is the sky's mean radiance over the upper hemisphere, k_a = 0.8.

**Cumulus in height (camera rays).**  A flat layer seen toward the horizon is foreshortened into
streaks, where real fair-weather cumulus show their sides: flat bases and domed tops stacked toward
the horizon.  So what a camera ray sees is a height field over the same pattern: a cumulus stands
on the layer's plane where the flat layer has cloud, as tall as

    y_top(x) − h = H · s(n − n₀; w) · √(clip((n − n₀)/(1 − n₀), 0, 1))                        (5)

(H = ``height``, by default 0.4 × ``scale``; s the edge's smoothstep of (2)), each cumulus topped at
its own share of H:

    (y_top(x) − h) ← (y_top(x) − h) · (1 − S·c·(1 − g(x))),   g = ½ m(x) + ½ v(x)           (5')

with S = :data:`TOWER_SPREAD`, m the group field of (2') (the tallest towers in a group's core) and v a
value noise :data:`TOWER_CELL` × ``scale`` across (cloud to cloud).  The ray marches it
between y = h and y = h + H at points at most :data:`STEP` × ``scale`` apart (:data:`MARCH` to
:data:`MARCH_MAX` of them: a grazing ray crosses many clouds; a coarser march misses some and shows
a thinner sky, 50 % of the demo's sky pixels clouded with 8 points against 65 % converged), offset
by one jitter per ray — the path's own sample, stratified over a pixel's samples (a hash of the
direction where none is given) — and stops once the ray is opaque (T < :data:`OPAQUE`):

    τ_k = σ · o(x_k) · Δt · f(t_k),   σ = 3D / H,   T = Π_k e^(−τ_k)                         (6)

with o ∈ [0, 1] how far x_k lies below the top (a soft top :data:`TOP_EDGE` · H thick), so a
vertical ray through a full tower meets τ = 3D, the flat layer's core.  The cloud's radiance is
taken at its front x_f, the mean of the points weighted by what each absorbs, T_k (1 − e^(−τ_k)):

    L_cloud = E_sun [ p_HG(ω·s; g) V + (ρ/π)(m + (1 − m) V) ] + k_a · L̄_sky · (b + (1 − b) η)  (7)

V = e^(−τ_s) the sunlight reaching x_f through the cumulus, τ_s = 0.15 σ Σ o(x_f + ℓ_j s) Δℓ_j at
the distances ℓ_j = :data:`SUN_STEPS` × H toward the sun (Schneider & Vos 2015's light march), m =
:data:`MULTIPLE` the light multiple scattering carries into the shade, η ∈ [0, 1] the front's
height as a share of its own cumulus' top (5') and b = :data:`BASE_AMBIENT` the sky light that
reaches a base: sunlit domes over grey bases.  Between the camera and a cloud tens of kilometres away lies air: its Rayleigh
extinction a = e^(−β_R ρ̄ |x_f − o|) (β_R = :data:`RAYLEIGH` per RGB channel, ρ̄ the air's density at
the path's mean height, scale height :data:`RAYLEIGH_HEIGHT`) dims the cloud, and the light the air
scatters in is taken as the clear sky's toward ω:

    L = T·(L_sky + L_sun) + (1 − T)·(a·L_cloud + (1 − a)·L_sky)                               (8)

so far cumulus turn to the sky's blue instead of a cream band at the horizon (at 40 km along a path
1 km up on average, a = 0.82, 0.62, 0.31).  Only camera rays see (5)–(8), in a branch a packet without a camera ray that left
the scene skips; bounce rays and light samples see the flat layer (3)–(4), whose cover is the
cumulus' footprint, so the ground's light and the cloud shadows are as before and both MIS
strategies still evaluate the same radiance (a camera ray has no light-sampling alternative).
``height = 0`` gives camera rays the flat layer too.

**Unbiased light sampling.**  (3) is the radiance of every light that leaves the scene —
camera, bounce and next-event rays alike (:class:`~.emitters.LightSet` evaluates it for all of them
from the ray's origin).  forest_path's light-sampling densities do not depend on the clouds
(cosine-weighted for the constant and gradient skies, Mitsuba's clear-sky density for ``sunsky`` and
``envmap``, the cone for the sun), and both strategies evaluate the same L, so the MIS estimate stays
unbiased: clouds over the sun cast shadows (T on the sun's radiance), clouds in the sky light the
ground by their own radiance.  The haze (:mod:`.haze`) keeps the clear sky's colour.

Cost: a few dozen arithmetic operations and 20 hashes per sky evaluation; the sky is evaluated once
per escaped ray and once per light sample — in the measurements of ``docs/rendering.md``, a few per
cent of a frame.  The cumulus add 3 fBm evaluations and a march of up to :data:`MARCH_MAX` per camera
ray that leaves the scene, most of which stop early at an opaque cloud (``bench/bench_clouds.py``: 1.02×
the render's CPU time of the flat layer on the demo).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: Octaves of the fBm, their gain, and the Henyey–Greenstein g of the silver lining.
OCTAVES = 5
GAIN = 0.5
PHASE_G = 0.6
#: Single-scattering albedo of the sunlit cloud seen from below, and the ambient share of the sky's mean.
ALBEDO = 0.9
AMBIENT = 0.8
#: Two-stream diffusion constant (3/4)(1 − g_c) of a cloud slab, g_c ≈ 0.8 for cloud droplets.
DIFFUSION = 0.15
#: Distance fade f(t) = exp(−t / (FADE · altitude)).
FADE = 30.0
#: Thickness of the layer as a fraction of ``scale`` (the self-shadow's step toward the sun).
THICKNESS = 0.25
#: Jittered grid on which the pattern's (1 − cover) quantile is measured (side, and its span in units of ``scale``:
#: dozens of the groups of equation (2')).
QUANTILE_GRID = 512
QUANTILE_SPAN = 256.0
#: Directions this close to the horizon (ω_y) see no cloud.
MIN_MU = 1e-3
#: Camera rays: the cumulus' tallest height above the layer's base, as a fraction of ``scale``.
TOWER = 0.4
#: Camera rays: the march through the cumulus' height takes points at most STEP × ``scale`` apart along the ray,
#: at least MARCH and at most MARCH_MAX of them, and stops once the ray's transmittance falls below OPAQUE.
MARCH = 8
MARCH_MAX = 64
STEP = 0.15
OPAQUE = 1e-3
#: Camera rays: the distances toward the sun, as fractions of the tallest cumulus, of the light march.
SUN_STEPS = (0.15, 0.5, 1.2)
#: Camera rays: the soft edge of a cumulus' top, as a fraction of its tallest height.
TOP_EDGE = 0.05
#: Camera rays: the share of the sunlit radiance that multiple scattering carries into a cloud's shade.
MULTIPLE = 0.15
#: Camera rays: the share of the sky's ambient light that reaches a cumulus' base (its top takes all of it).
BASE_AMBIENT = 0.4
#: Clouds gather into groups: a field CLUSTER × ``scale`` across raises or lowers the pattern's noise by up to
#: ± CLUSTER_GAIN / 2 × ``clustering`` (equation (2')).
CLUSTER = 6.0
CLUSTER_GAIN = 0.5
#: Camera rays: cumulus differ in height: each one's tallest is (1 − TOWER_SPREAD × ``clustering`` × (1 − g)) × H,
#: g ∈ [0, 1] half the group field and half a field TOWER_CELL × ``scale`` across (one value per cloud or two).
TOWER_SPREAD = 0.6
TOWER_CELL = 1.5
#: Camera rays: Rayleigh scattering coefficients of air at sea level for red, green and blue (680, 550, 440 nm),
#: per metre, and the scale height of its density, metres (Bruneton & Neyret 2008, "Precomputed atmospheric
#: scattering", EGSR).
RAYLEIGH = (5.8e-6, 13.5e-6, 33.1e-6)
RAYLEIGH_HEIGHT = 8000.0


def _hash(mi: Any, ix: Any, iy: Any, seed: int) -> Any:
    """A uniform float in [0, 1) from integer lattice coordinates and a seed (xorshift–multiply mixer)."""
    import drjit as dr

    u = mi.UInt32
    h = dr.reinterpret_array(u, ix) * u(0x8DA6B343) ^ dr.reinterpret_array(u, iy) * u(0xD8163841)
    h = h ^ u((seed * 0x9E3779B9) & 0xFFFFFFFF)
    h = (h ^ (h >> 16)) * u(0x7FEB352D)
    h = (h ^ (h >> 15)) * u(0x846CA68B)
    h = h ^ (h >> 16)
    return mi.Float(h >> 8) * (1.0 / 16777216.0)


def _fade(t: Any) -> Any:
    """Perlin's (2002) quintic fade 6t⁵ − 15t⁴ + 10t³."""
    import drjit as dr

    return t * t * t * dr.fma(t, dr.fma(t, 6.0, -15.0), 10.0)


def value_noise(mi: Any, x: Any, y: Any, seed: int) -> Any:
    """2-D value noise in [0, 1): lattice hashes at the four corners, blended by the quintic fade."""
    import drjit as dr

    fx, fy = dr.floor(x), dr.floor(y)
    ix, iy = mi.Int32(fx), mi.Int32(fy)
    ux, uy = _fade(x - fx), _fade(y - fy)
    a = _hash(mi, ix, iy, seed)
    b = _hash(mi, ix + 1, iy, seed)
    c = _hash(mi, ix, iy + 1, seed)
    d = _hash(mi, ix + 1, iy + 1, seed)
    return dr.lerp(dr.lerp(a, b, ux), dr.lerp(c, d, ux), uy)


def fbm(mi: Any, x: Any, y: Any, seed: int) -> Any:
    """fBm of :func:`value_noise`, normalised to [0, 1): octaves rotated by ≈ 36.9° and shifted."""
    amp, norm = 1.0, 0.0
    total: Any = 0.0
    for i in range(OCTAVES):
        total = total + value_noise(mi, x, y, seed + 1013 * i) * amp
        norm += amp
        amp *= GAIN
        x, y = 1.6 * x - 1.2 * y + 17.31, 1.2 * x + 1.6 * y - 9.71  # 2 × rotation (0.8, −0.6; 0.6, 0.8)
    return total * (1.0 / norm)


def henyey_greenstein(mu: Any, g: float) -> Any:
    """p_HG(μ; g) = (1 − g²) / (4π (1 + g² − 2gμ)^(3/2)), per steradian."""
    import drjit as dr

    k = 1.0 + g * g - 2.0 * g * mu
    return (1.0 - g * g) / (4.0 * math.pi) * dr.rsqrt(k * k * k)


class CloudLayer:
    """The cloud layer of a :class:`forest.lights.Clouds` description, evaluated in drjit (module docstring)."""

    def __init__(self, mi: Any, clouds: Any):
        self.mi = mi
        self.cover = float(clouds.cover)
        self.altitude = float(clouds.altitude)
        self.scale = float(clouds.scale)
        self.seed = int(clouds.seed) & 0x7FFFFFFF
        self.density = float(clouds.density)
        self.softness = float(clouds.softness)
        self.wind = (float(clouds.wind[0]), float(clouds.wind[1]))
        #: How much the clouds gather into groups and differ in height, c ∈ [0, 1] (equations (2') and (5')).
        self.clustering = float(getattr(clouds, "clustering", 0.0))
        height = getattr(clouds, "height", None)
        #: The tallest cumulus above the layer, metres, as camera rays see them (0: the flat layer).
        self.tall = TOWER * self.scale if height is None else float(height)
        #: The cumulus' extinction σ = 3D/H, per metre (equation (6)): a vertical ray through a full tower meets 3D.
        self.sigma = 3.0 * self.density / self.tall if self.tall > 0.0 else 0.0
        self.threshold = self._quantile(1.0 - self.cover)

    def _quantile(self, q: float) -> float:
        """The pattern's q-quantile, measured on a fixed grid (deterministic)."""
        import drjit as dr

        mi = self.mi
        # Jittered grid points (a fixed stream): a regular grid would sample the lattice at a few fixed offsets.
        g = np.arange(QUANTILE_GRID, dtype=np.float64) * (QUANTILE_SPAN / QUANTILE_GRID)
        gx, gy = (a.ravel() for a in np.meshgrid(g, g))
        jitter = np.random.default_rng(0x0C10D).uniform(0.0, QUANTILE_SPAN / QUANTILE_GRID, (2, gx.size))
        gx, gy = (gx + jitter[0]).astype(np.float32), (gy + jitter[1]).astype(np.float32)
        with dr.suspend_grad():
            n = np.asarray(self._pattern(mi.Float(gx), mi.Float(gy))[0], np.float64)
        return float(np.quantile(n, min(max(q, 0.0), 1.0)))

    def _groups(self, u: Any, v: Any) -> Any:
        """The group field m ∈ [0, 1) at pattern coordinates (u, v) (units of ``scale``): value noise CLUSTER
        × ``scale`` across, its lattice turned by ≈ 36.9° so no axis shows."""
        k = 1.0 / CLUSTER
        return value_noise(self.mi, (0.8 * u - 0.6 * v) * k + 5.3, (0.6 * u + 0.8 * v) * k - 2.9, self.seed + 7919)

    def _pattern(self, u: Any, v: Any) -> tuple[Any, Any]:
        """The pattern's noise at (u, v) (units of ``scale``), equation (2'), and the group field there (None
        when ``clustering`` is 0): n' = n + c · CLUSTER_GAIN · (m − ½)."""
        n = fbm(self.mi, u, v, self.seed)
        if self.clustering <= 0.0:
            return n, None
        m = self._groups(u, v)
        return n + (self.clustering * CLUSTER_GAIN) * (m - 0.5), m

    def _coords(self, x: Any, z: Any) -> tuple[Any, Any]:
        """Layer coordinates (x, z), metres, to the pattern's (units of ``scale``, the wind taken off)."""
        inv = 1.0 / self.scale
        return (x - self.wind[0]) * inv, (z - self.wind[1]) * inv

    def thickness(self, x: Any, z: Any) -> Any:
        """Optical thickness τ at layer coordinates (x, z) in metres, equation (2)."""
        import drjit as dr

        n, _ = self._pattern(*self._coords(x, z))
        excess = n - self.threshold
        edge = dr.clip(excess * (1.0 / self.softness), 0.0, 1.0)
        body = 1.0 + 2.0 * dr.maximum(excess, 0.0) * (1.0 / max(1.0 - self.threshold, 1e-3))
        return self.density * edge * edge * (3.0 - 2.0 * edge) * body

    def profile(self, x: Any, z: Any) -> Any:
        """A cumulus' height at layer coordinates (x, z) as a fraction of the tallest, p ∈ [0, 1], equation (5):
        0 where the flat layer is clear, rising with the noise past its threshold as a dome (√), each cloud
        topped at its own :meth:`tower`."""
        import drjit as dr

        u, v = self._coords(x, z)
        n, m = self._pattern(u, v)
        excess = n - self.threshold
        edge = dr.clip(excess * (1.0 / self.softness), 0.0, 1.0)
        body = dr.clip(excess * (1.0 / max(1.0 - self.threshold, 1e-3)), 0.0, 1.0)
        dome = edge * edge * (3.0 - 2.0 * edge) * dr.sqrt(body)
        return dome if m is None else dome * self._tower(u, v, m)

    def _tower(self, u: Any, v: Any, m: Any) -> Any:
        """The tallest a cumulus at pattern coordinates (u, v) rises, as a fraction of H (equation (5')):
        1 − TOWER_SPREAD · c · (1 − g), g = ½ m + ½ v_c with m the group field (taller in a group's core) and
        v_c value noise TOWER_CELL × ``scale`` across (cloud to cloud)."""
        k = 1.0 / TOWER_CELL
        cell = value_noise(self.mi, (0.6 * u + 0.8 * v) * k - 11.7, (0.8 * v - 0.6 * u) * k + 3.1, self.seed + 4271)
        return 1.0 - (TOWER_SPREAD * self.clustering) * (1.0 - 0.5 * (m + cell))

    def tower(self, x: Any, z: Any) -> Any:
        """The tallest a cumulus standing at layer coordinates (x, z) rises, as a fraction of ``height``."""
        if self.clustering <= 0.0:
            return self.mi.Float(1.0)
        u, v = self._coords(x, z)
        return self._tower(u, v, self._groups(u, v))

    def _occupancy(self, x: Any, y: Any, z: Any) -> Any:
        """How far inside a cumulus the point (x, y, z) is, in [0, 1]: 1 below its top, 0 above, a soft top."""
        import drjit as dr

        tall = self.tall
        top = self.profile(x, z) * tall
        return dr.select(top > 0.0, dr.clip((top - (y - self.altitude)) * (1.0 / (TOP_EDGE * tall)), 0.0, 1.0), 0.0)

    def cumulus(self, o: Any, d: Any, active: Any, jitter: Any = None) -> tuple[Any, Any, Any]:
        """What a camera ray (o, d) sees of the cumulus, equations (5)–(6): (T, the front point where it meets
        them as a Point3f, the share of the ray's light the cumulus took); the march's points are offset by
        ``jitter`` ∈ [0, 1) (the path's own sample, stratified over a pixel's samples; None: a hash of d)."""
        import drjit as dr

        mi = self.mi
        tall, sigma = self.tall, self.sigma
        up = active & (d.y > MIN_MU) & (o.y < self.altitude)
        inv_dy = 1.0 / dr.maximum(d.y, MIN_MU)
        t0 = (self.altitude - o.y) * inv_dy
        span = tall * inv_dy
        # One jitter per ray: the path's own sample, or else a hash of its direction (deterministic either way).
        if jitter is None:
            bits: Any = dr.reinterpret_array(mi.Int32, d.x)
            bits = bits ^ dr.reinterpret_array(mi.Int32, d.z)
            jitter = _hash(mi, bits, dr.reinterpret_array(mi.Int32, d.y), self.seed ^ 0x5A17)
        fade = -1.0 / (FADE * self.altitude)
        # Points at most STEP × scale apart (a grazing ray crosses many clouds), MARCH to MARCH_MAX of them.
        count = dr.clip(dr.ceil(span * (1.0 / (STEP * self.scale))), MARCH, MARCH_MAX)
        step = span / count
        n = dr.select(up, mi.UInt32(count), 0)

        def body(k: Any, T: Any, weight: Any, front: Any) -> tuple[Any, Any, Any, Any]:
            t = dr.fma(mi.Float(k) + jitter, step, t0)
            p = dr.fma(d, t, o)
            occ = self._occupancy(p.x, p.y, p.z)
            absorbed = T * (1.0 - dr.exp(-sigma * occ * step * dr.exp(t * fade)))
            return k + 1, T - absorbed, weight + absorbed, dr.fma(mi.Vector3f(p), absorbed, front)

        _, T, weight, front = dr.while_loop(
            (mi.UInt32(0), mi.Float(1.0), mi.Float(0.0), mi.Vector3f(0.0)),
            lambda k, T, *_: (k < n) & (T > OPAQUE),
            body,
            label="forest_path: cumulus march",
        )
        front = mi.Point3f(front / dr.maximum(weight, 1e-12))
        return T, front, weight

    def crossing(self, o: Any, d: Any, active: Any) -> tuple[Any, Any, Any, Any]:
        """Where a ray crosses the layer, equation (1): (x, z, t, whether it does)."""
        import drjit as dr

        up = active & (d.y > MIN_MU) & (o.y < self.altitude)
        t = dr.select(up, (self.altitude - o.y) / dr.maximum(d.y, MIN_MU), 0.0)
        return dr.fma(d.x, t, o.x), dr.fma(d.z, t, o.z), t, up

    def transmittance(self, o: Any, d: Any, active: Any) -> tuple[Any, Any, Any, Any]:
        """(T, τ, x, z) of the layer along the ray (o, d): T = exp(−τ f(t)), 1 where it misses the layer."""
        import drjit as dr

        x, z, t, up = self.crossing(o, d, active)
        tau = dr.select(up, self.thickness(x, z) * dr.exp(t * (-1.0 / (FADE * self.altitude))), 0.0)
        return dr.exp(-tau), tau, x, z

    def _cumulus_light(
        self, o: Any, d: Any, active: Any, sky: Any, sun: Any, sun_term: Any, ambient: Any, jitter: Any = None
    ) -> Any:
        """(sky, sun) radiances toward ``d`` for camera rays, through the cumulus (equations (5)–(7))."""
        import drjit as dr

        mi = self.mi
        T, front, _ = self.cumulus(o, d, active, jitter)
        veil = 1.0 - T
        tall = self.tall
        # η: the front's height in its own cumulus (a short one's top takes the sky's light as a tall one's does).
        height = dr.clip((front.y - self.altitude) / (tall * self.tower(front.x, front.z)), 0.0, 1.0)
        # The air between the camera and the cloud, equation (8): Rayleigh extinction at the path's mean height,
        # its in-scattered light taken as the clear sky's toward d.
        density = dr.exp(-0.5 * (o.y + front.y) * (1.0 / RAYLEIGH_HEIGHT))
        air = dr.exp(mi.Color3f(*[-b for b in RAYLEIGH]) * (dr.norm(front - o) * density))
        glow = AMBIENT * ambient * dr.fma(height, 1.0 - BASE_AMBIENT, BASE_AMBIENT)
        sky_out = dr.fma(sky, T, veil * (air * glow + (1.0 - air) * sky))
        if sun_term is None:
            return sky_out, sun * T
        s, e_sun = sun_term
        tau_s = mi.Float(0.0)
        last = 0.0
        for f in SUN_STEPS:
            q = dr.fma(s, f * tall, front)
            tau_s += self._occupancy(q.x, q.y, q.z) * ((f - last) * tall)
            last = f
        tau_s = DIFFUSION * self.sigma * tau_s
        mu = dr.dot(d, s)
        shade = dr.exp(-tau_s)
        lit = henyey_greenstein(mu, PHASE_G) * shade + (ALBEDO / math.pi) * (MULTIPLE + (1.0 - MULTIPLE) * shade)
        lit = dr.select(s.y > 0.0, lit, 0.0)
        return sky_out, dr.fma(sun, T, mi.Color3f(e_sun) * air * (veil * lit))

    def apply(
        self,
        o: Any,
        d: Any,
        active: Any,
        sky: Any,
        sun: Any,
        sun_term: tuple[Any, Any] | None,
        ambient: Any,
        camera: Any = None,
        jitter: Any = None,
    ) -> tuple[Any, Any]:
        """The clouded (sky, sun) radiances toward ``d`` from ``o``, equations (3)–(4).

        ``sky`` and ``sun`` are the clear sky's and the sun's radiance toward d; ``sun_term`` is (unit
        vector toward the sun as a Vector3f, its RGB irradiance E_sun) or None; ``ambient`` the sky's
        mean radiance (RGB).  The cloud's sunlit radiance joins the sun's share and its ambient the sky's,
        so light groups still add up to the total.
        """
        import drjit as dr

        mi = self.mi
        T, tau, x, z = self.transmittance(o, d, active)
        veil = 1.0 - T
        sky_out = dr.fma(sky, T, veil * AMBIENT * ambient)
        if sun_term is None:
            return sky_out, sun * T
        s, e_sun = sun_term
        mu = dr.dot(d, s)
        hop = THICKNESS * self.scale / dr.maximum(s.y, 0.05)
        tau_s = self.thickness(dr.fma(s.x, hop, x), dr.fma(s.z, hop, z))
        lit = henyey_greenstein(mu, PHASE_G) * dr.exp(-0.5 * tau)
        lit += (ALBEDO / math.pi) / dr.fma(DIFFUSION, tau + tau_s, 1.0)
        lit = dr.select(s.y > 0.0, lit, 0.0)
        sky_out, sun_out = sky_out, dr.fma(sun, T, mi.Color3f(e_sun) * (veil * lit))
        if camera is None or self.tall <= 0.0:
            return sky_out, sun_out
        # Camera rays see the cumulus in height, in a branch a packet without camera rays skips.
        u = jitter if jitter is not None else mi.Float(-1.0)  # < 0: hash the jitter from the direction
        return dr.if_stmt(
            (o, d, sky, sun, ambient, sky_out, sun_out, u),
            camera,
            lambda *a: self._cumulus_light(
                a[0], a[1], True, a[2], a[3], sun_term, a[4], None if jitter is None else a[7]
            ),
            lambda *a: (a[5], a[6]),
            label="forest_path: cumulus",
        )
