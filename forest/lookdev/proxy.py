"""The differentiable stand-in for a forest scene, and the knobs the optimiser turns.

:class:`Proxy` wraps a Mitsuba scene loaded in a JIT variant (``llvm_ad_rgb``,
``cuda_ad_rgb``) and knows which of its parameters are the look:

* every ``volume`` texture over the colour grid (``….volume.data``), each with
  the base colour it multiplies (a tinted part's colour, the terrain colour):
  ``data = grid ⊙ base`` with the grid in the map convention, laid out
  (z, y=1, x, c) as in :func:`forest.render.scene.colour_grid_texture`;
* the ``directional`` sun (``sun.irradiance.value``, ``sun.to_world``);
* the sky: ``constant`` (``sky.radiance.value``) or ``envmap`` (``sky.scale``).

The render is the production image's: with ``[render] haze`` the proxy applies
the same aerial perspective, L·e^(−σd) + H·(1 − e^(−σd)), with the depth of
each pixel centre's hit — in drjit, so that the sky (which sets H unless
``haze_colour`` does) gets its share of the gradient.

How the forest becomes a scene that a JIT variant can differentiate quickly
is :mod:`forest.lookdev.forest_proxy`'s business; this module only needs the
loaded scene and the names above.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ForestError
from ..render.scene import sun_vector


def sampler_spp(spp: int) -> int:
    """The sample count the proxy's ``multijitter`` sampler uses for ``spp``: a·⌈spp/a⌉ with a = ⌊√spp⌋.

    Rounding here, as the sampler would, keeps Mitsuba from warning on every render.
    """
    a = max(1, math.isqrt(int(spp)))
    return a * -(-int(spp) // a)


def _sampling(seed: int, spp: int) -> tuple[int, int]:
    """(seed, spp) as Mitsuba takes them: a 32-bit seed, the sampler's own sample count."""
    return int(seed) & 0xFFFFFFFF, sampler_spp(spp)


@dataclass
class GridTarget:
    key: str
    base: np.ndarray  # (3,) linear RGB multiplied by the grid


@dataclass
class Proxy:
    mi: object
    scene: object
    width: int
    height: int
    grid_shape: tuple[int, int]
    grid_targets: list[GridTarget]
    sun_key: str | None = None
    sky_kind: str | None = None  # "constant" | "envmap" | None
    sky_key: str | None = None
    stats: dict = field(default_factory=dict)
    haze: float = 0.0  # [render] haze: extinction per metre (aerial perspective)
    haze_colour: tuple | None = None  # [render] haze_colour; None: the sky's radiance
    grid_extent: tuple | None = None  # (xmin, zmin, xmax, zmax) the colour grid spans
    gain: tuple | None = None  # per-channel calibration of hit pixels (see .calibrate)

    def __post_init__(self):
        self.variant = self.mi.variant()
        self.params = self.mi.traverse(self.scene)
        for t in self.grid_targets:
            if t.key not in self.params:
                raise ForestError(f"look-dev proxy: scene has no parameter {t.key}")
        n, m = self.grid_shape
        self._tiled = [self.mi.Float(np.tile(np.asarray(t.base, np.float32), n * m)) for t in self.grid_targets]

    def activate(self) -> None:
        """Make this proxy's variant Mitsuba's current one (another render may have switched it)."""
        from ..runtime import mitsuba

        mitsuba(self.variant)

    # -- writing the look into the scene -------------------------------------------------
    def set_grid(self, grid_flat) -> None:
        """``grid_flat``: drjit Float of n·m·3 values (map convention, channel fastest)."""
        mi = self.mi
        n, m = self.grid_shape
        for t, base in zip(self.grid_targets, self._tiled):
            self.params[t.key] = mi.TensorXf(grid_flat * base, (n, 1, m, 3))

    def set_sun(self, rgb) -> None:
        if self.sun_key is not None:
            self.params[self.sun_key] = rgb

    def set_sky(self, value) -> None:
        if self.sky_key is not None:
            self.params[self.sky_key] = value
            self._sky_value = value

    def set_sun_direction(self, elevation: float, azimuth: float) -> None:
        if self.sun_key is None:
            return
        mi = self.mi
        d = -sun_vector(elevation, azimuth)
        up = [0.0, 1.0, 0.0] if abs(d[1]) < 0.999 else [1.0, 0.0, 0.0]
        self.params["sun.to_world"] = mi.Transform4f().look_at(
            origin=[0.0, 0.0, 0.0], target=[float(x) for x in d], up=up
        )

    def set_state(self, state, *, direction: bool = True) -> None:
        """Write a numpy :class:`~forest.lookdev.state.LookState` (no gradients)."""
        self.activate()
        mi = self.mi
        self.set_grid(mi.Float(np.asarray(state.grid, np.float32).ravel()))
        if state.sun_irradiance is not None:
            self.set_sun(mi.Color3f(*[float(x) for x in state.sun_rgb()]))
            if direction and state.sun_elevation is not None:
                self.set_sun_direction(state.sun_elevation, state.sun_azimuth)
        if self.sky_kind == "constant" and state.sky_radiance is not None:
            self.set_sky(mi.Color3f(*[float(x) for x in state.sky_rgb()]))
        elif self.sky_kind == "envmap" and state.envmap_scale is not None:
            self.set_sky(mi.Float(float(state.envmap_scale)))
        self.params.update()

    # -- rendering ---------------------------------------------------------------------------
    def render(self, spp: int, seed: int, *, grad: bool = False):
        """Render the current parameters; with ``grad`` the result is attached to the AD graph."""
        self.activate()
        mi = self.mi
        seed, spp = _sampling(seed, spp)
        if grad:
            img = mi.render(self.scene, self.params, seed=seed, spp=spp, spp_grad=spp)
        else:
            img = mi.render(self.scene, seed=seed, spp=spp)
        img = self._hazed(img) if self.haze > 0 else img
        return self._gained(img) if self.gain is not None else img

    def set_gain(self, gain) -> None:
        """Multiply the pixels that hit the scene by ``gain`` (3,) from now on (None: no gain)."""
        self.gain = None if gain is None else tuple(float(x) for x in gain)
        self._gain_arr = None

    def _gain_values(self) -> np.ndarray:
        hit = self._primary_hits()[0].ravel()
        return np.where(hit[:, None], np.asarray(self.gain, np.float64)[None, :], 1.0).ravel()

    def _gained(self, img):
        if getattr(self, "_gain_arr", None) is None:
            self._gain_arr = self.mi.Float(self._gain_values().astype(np.float32))
        return self.mi.TensorXf(img.array * self._gain_arr, (self.height, self.width, img.shape[2]))

    def grid_tangent(self, grid: np.ndarray, tangent: np.ndarray, spp: int, seed: int) -> np.ndarray:
        """The render's forward-mode derivative along ``tangent`` of the grid at ``grid``: (H, W, 3).

        Both are flat n·m·3 arrays (map convention, channel fastest).  The
        tangent is set on each grid texture's data (times its base colour) and
        the integrator's ``render_forward`` propagates it; with haze the
        derivative is attenuated by the same transmittance as the radiance.
        """
        import drjit as dr

        self.activate()
        mi = self.mi
        n, m = self.grid_shape
        g = np.asarray(grid, np.float32).ravel()
        tg = np.asarray(tangent, np.float32).ravel()
        keys = []
        for t, base in zip(self.grid_targets, self._tiled):
            b = np.asarray(base, np.float32)
            value = mi.TensorXf(mi.Float(g * b), (n, 1, m, 3))
            dr.enable_grad(value)
            dr.set_grad(value, mi.TensorXf(mi.Float(tg * b), (n, 1, m, 3)))
            self.params[t.key] = value
            keys.append(t.key)
        self.params.update()
        # Push the tangent into the textures' internal copies before the integrator's isolated pass.
        dr.enqueue(dr.ADMode.Forward, *[self.params[k] for k in keys])
        dr.traverse(dr.ADMode.Forward, dr.ADFlag.ClearEdges)
        seed, spp = _sampling(seed, spp)
        out = self.scene.integrator().render_forward(self.scene, self.params, seed=seed, spp=spp)
        arr = np.asarray(dr.detach(out), np.float64)[..., :3]
        for key in keys:
            self.params[key] = dr.detach(self.params[key])
        self.params.update()
        if self.haze > 0:
            self._hazed_setup()
            arr = arr * np.asarray(self._haze_t, np.float64).reshape(arr.shape)
        if self.gain is not None:
            arr = arr * self._gain_values().reshape(arr.shape)
        return arr

    def _hazed_setup(self) -> None:
        if getattr(self, "_haze_t", None) is None:
            hit, depth = self._primary_hits()
            t = np.where(hit, np.exp(-self.haze * depth), 1.0).astype(np.float32).ravel()
            self._haze_t = self.mi.Float(np.repeat(t, 3))

    def _hazed(self, img):
        """Aerial perspective as the production render applies it: L·T + H·(1 − T), T = e^(−σd) on hits.

        d is the distance to the surface seen through the pixel centre; H is
        ``haze_colour``, else the sky's current radiance (a constant sky, so the
        fitted sky also drives the haze, as it will in the written scene), else
        the renderer's default (0.5, 0.6, 0.75).
        """
        import drjit as dr

        mi = self.mi
        self._hazed_setup()
        if self.haze_colour is not None:
            h = mi.Color3f(*[float(x) for x in self.haze_colour])
        elif self.sky_kind == "constant" and getattr(self, "_sky_value", None) is not None:
            h = self._sky_value
        else:
            h = mi.Color3f(0.5, 0.6, 0.75)
        idx = mi.UInt32(np.arange(self.width * self.height * 3, dtype=np.uint32) % 3)
        hc = dr.select(idx == 0, h.x, dr.select(idx == 1, h.y, h.z))
        arr = img.array * self._haze_t + hc * (1.0 - self._haze_t)
        return mi.TensorXf(arr, (self.height, self.width, img.shape[2]))

    def render_numpy(self, spp: int, seed: int, *, passes: int = 1) -> np.ndarray:
        """A detached render averaged over ``passes`` independently seeded passes: (H, W, 3) float32."""
        acc = None
        for k in range(passes):
            img = np.asarray(self.render(spp, seed * 7919 + k), dtype=np.float64)[..., :3]
            acc = img if acc is None else acc + img
        return (acc / passes).astype(np.float32)

    def _primary_hits(self) -> tuple[np.ndarray, np.ndarray]:
        """(hit, distance), each (H, W), of the rays through the pixel centres."""
        if getattr(self, "_hits", None) is None:
            self.activate()
            mi = self.mi
            import drjit as dr

            sensor = self.scene.sensors()[0]
            h, w = self.height, self.width
            jj, ii = np.meshgrid(np.arange(w), np.arange(h))
            pos = mi.Point2f(
                mi.Float(((jj.ravel() + 0.5) / w).astype(np.float32)),
                mi.Float(((ii.ravel() + 0.5) / h).astype(np.float32)),
            )
            ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
            si = self.scene.ray_intersect(ray)
            valid = np.asarray(dr.detach(si.is_valid()), dtype=bool).reshape(h, w)
            t = np.asarray(dr.detach(si.t), dtype=np.float64).reshape(h, w)
            self._hit_xz = np.stack(
                [
                    np.asarray(dr.detach(si.p.x), np.float64).reshape(h, w),
                    np.asarray(dr.detach(si.p.z), np.float64).reshape(h, w),
                ],
                axis=-1,
            )
            self._hits = (valid, np.where(valid, t, 0.0))
        return self._hits

    def pixel_cells(self) -> np.ndarray:
        """(H, W, 2) int: the colour-grid cell (row, column) under each pixel centre's hit; −1 for the sky."""
        valid = self._primary_hits()[0]
        n, m = self.grid_shape
        xmin, zmin, xmax, zmax = self.grid_extent
        col = np.clip(np.floor((self._hit_xz[..., 0] - xmin) / (xmax - xmin) * m), 0, m - 1).astype(np.int64)
        row = np.clip(np.floor((self._hit_xz[..., 1] - zmin) / (zmax - zmin) * n), 0, n - 1).astype(np.int64)
        return np.where(valid[..., None], np.stack([row, col], axis=-1), -1)

    def sky_mask(self) -> np.ndarray:
        """(H, W) bool: pixels whose centre ray escapes to the sky (nothing hit)."""
        return ~self._primary_hits()[0]
