"""The production scene rendered for a fit: the forest path tracer at reduced resolution and samples.

:class:`FitRenderer` builds one :class:`forest.render.path.PathScene` from the
Scene exactly as the production render does (:func:`forest.render.path.from_scene.path_inputs`):
every tree of the InstanceSet at the camera's levels of detail — no frustum
culling, so trees outside the frame still cast their shadows and bounce their
light into it — with the terrain, the ground skirt, the colour map, the lights
and the haze.  Three changes, all exact at the start: a constant sky becomes the
``gradient`` sky with equal zenith and horizon (so the fit can tilt it), a fit
of the haze without one in the config starts from a haze of density 0 (which
renders nothing), and the colour map is the base of :mod:`.correction` (the
painted map, or its cells for a fresh grid).  The fit's renders stratify their
samples as production does (:data:`FIT_SAMPLER`): the aligned loss weighs each
block by its own relative noise (:class:`.losses.PixelLoss`), whatever its spread
over the frame, so the lower noise is a gain everywhere.

What a fit asks of it (all images (H, W, 3), linear, at the fit's size):

* :meth:`light_images` — U_k, the image lit by light k alone at unit scale; the
  render is linear in each light's RGB scale s_k and in the haze's radiance C
  (a "light" of its own here: the haze's ambient source, :mod:`forest.render.path.haze`)
  and channel-separable, so I = Σ_k s_k ⊙ U_k exactly (one primal render per light);
* :meth:`log_derivative` — ∂I/∂ln m for a multiplier m of leaf albedos (all
  species or one), the ground albedo, or a class of colour-map cells, by
  forward-mode path replay (:meth:`PathScene.render_forward`) with the tangent
  dm = m: channel c of the image depends on channel c of m only, so one pass
  gives all three channels' derivatives;
* :meth:`render` — the image at the current look (held-out evaluations);
* :attr:`layers` — depth, tree id and species per pixel centre, the world
  position of each pixel's hit, its ray direction and the optical length of its
  camera segment through the haze (regions, the haze step, cells).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from ..lights import DEFAULT_SUN
from ..render.path import PathScene, SkyLight
from ..render.path.arrays import mappable, opaque
from ..render.path.emitters import SkyBasis
from ..render.path.from_scene import haze_inputs, path_inputs
from .colour import luminance
from .daylight import rgb_to_cct
from .image_model import optical_length
from .params import Start

if TYPE_CHECKING:
    from ..config import Config
    from ..scene import Scene

#: The sampler of the fit's renders (see the module docstring).
FIT_SAMPLER = "multijitter"


def _leaf_colours(scene: Scene) -> np.ndarray:
    """(S, 3) mean colour of each species' leaf parts at its first level (for albedo bounds)."""
    out = []
    for sp in scene.species:
        first = sp[0] if isinstance(sp, (list, tuple)) else sp
        cols = [np.asarray(p.colour, np.float64) for p in first.lods[0].parts if getattr(p, "kind", "") == "leaf"]
        out.append(np.mean(cols, axis=0) if cols else np.full(3, 0.1))
    return np.asarray(out).reshape(-1, 3)


def species_labels(config: Config) -> list[str]:
    """A label per species index: ``[[species]] name`` or its ``model``."""
    return [s.name or s.model for s in config.species]


class FitRenderer:
    """The Scene as the fit renders it (see the module docstring)."""

    def __init__(
        self,
        scene: Scene,
        *,
        width: int,
        height: int,
        spp: int,
        variant: str,
        base_map: np.ndarray | None,
        haze: bool = False,
    ):
        config = scene.config
        inputs = replace(path_inputs(scene, width=width, height=height, spp=spp), sampler=FIT_SAMPLER)
        if haze and inputs.haze is None:
            # The config's haze settings at density 0: renders as no haze, ready to be fitted.
            hz = haze_inputs(config.with_overrides({"render.haze": 1e-6}), scene.terrain)
            inputs = replace(inputs, haze=None if hz is None else replace(hz, density=0.0))
        if inputs.haze is not None:
            # Light shafts are a primal-only estimate (forest.render.path.integrator): fits use the lit haze.
            inputs = replace(inputs, haze=replace(inputs.haze, shafts=False))
        sky = inputs.sky
        self.gradient = sky is not None and sky.kind == "constant"
        if sky is not None and self.gradient:
            rad = tuple(float(x) for x in sky.radiance)
            inputs = replace(inputs, sky=SkyLight("gradient", zenith=rad, horizon=rad))
        if base_map is not None:
            inputs = replace(inputs, colour_grid=np.asarray(base_map, np.float32))
        self.inputs = inputs
        self.scene = PathScene(inputs, variant)
        self.mi = self.scene.mi
        self.variant = variant
        self.width, self.height, self.spp = int(width), int(height), int(spp)
        self.n_species = len(inputs.species)
        self.light_params = [light.param for light in self.scene.lights]
        self.haze = self.scene.haze  # HazeInputs with its colour resolved, or None
        if self.haze is not None:
            self.light_params.append("haze_colour")
        self.start = self._start(config, scene)
        self.layers = self._layers()

    # -- the start ------------------------------------------------------------------------
    def _start(self, config: Config, scene: Scene) -> Start:
        lights = scene.lights
        sun = lights.sun
        sky = lights.sky
        sun_on = sun is not None and not lights.sunsky and self.inputs.sun is not None  # a disc sun, on
        pose = sun if sun is not None else (sky.sun if sky is not None and sky.sun is not None else DEFAULT_SUN)
        e_sun = sun.rgb if sun is not None else np.zeros(3)
        sk, sd = rgb_to_cct(e_sun) if sun_on else (5500.0, 0.0)
        kind = None if sky is None else sky.kind
        sky_rgb = np.zeros(3)
        sky_power = 0.0
        sky_k, sky_d = 12000.0, 0.0
        if sky is not None and sky.kind == "constant":
            sky_rgb = sky.radiance
            sky_power = math.pi * float(luminance(sky_rgb))
            sky_k, sky_d = rgb_to_cct(sky_rgb)
        elif kind is not None:
            for light in self.scene.lights:
                if light.param == "sky_scale":
                    sky_power = float(light.power(light.initial))
        initial = {light.param: np.asarray(light.initial, np.float64).reshape(3) for light in self.scene.lights}
        ratio = np.ones(3)
        if self.haze is not None:
            hc = np.asarray(self.haze.colour, np.float64)
            base = sky_rgb if kind == "constant" else initial.get("sky_scale", np.ones(3))
            ratio = hc / np.maximum(base, 1e-9)
        tc = np.asarray(self.inputs.terrain_colour, np.float64)
        terrain = tc.reshape(-1, 3).mean(axis=0) if tc.ndim == 3 else tc.reshape(3)
        return Start(
            sun_elevation=float(pose.elevation),
            sun_azimuth=float(pose.azimuth),
            sun_on=bool(sun_on),
            sun_y=float(luminance(e_sun)) if sun_on else 0.0,
            sun_kelvin=sk,
            sun_duv=sd,
            sky_kind=kind,
            sky_rgb=sky_rgb,
            sky_power=sky_power,
            sky_kelvin=sky_k,
            sky_duv=sky_d,
            haze=0.0 if self.haze is None else float(self.haze.density),
            haze_ratio=ratio,
            terrain_colour=terrain,
            has_haze=self.haze is not None,
            initial=initial,
            ground_tint0=np.asarray(self.inputs.ground_tint, np.float64).reshape(3),
            leaf_tint0=self.inputs.tints()[0],
            leaf_colours=_leaf_colours(scene),
            species=species_labels(config),
        )

    # -- layers -------------------------------------------------------------------------
    def _layers(self) -> dict[str, np.ndarray]:
        lay = self.scene.layers()
        cam = self.inputs.camera
        w, h = self.width, self.height
        # The ray through each pixel centre: pinhole with horizontal fov, +X to the left (see PathCamera).
        tan_x = math.tan(math.radians(float(cam.fov)) / 2.0)
        tan_y = tan_x * h / w
        xs = (1.0 - 2.0 * (np.arange(w) + 0.5) / w) * tan_x
        ys = (1.0 - 2.0 * (np.arange(h) + 0.5) / h) * tan_y
        gx, gy = np.meshgrid(xs, ys)
        local = np.stack([gx, gy, np.ones_like(gx)], axis=-1)
        local /= np.linalg.norm(local, axis=-1, keepdims=True)
        m = np.asarray(cam.to_world, np.float64)
        dirs = local @ m[:3, :3].T
        depth = lay["depth"].astype(np.float64)
        far = float(cam.far)
        hit = depth < far * 0.999
        pos = m[:3, 3] + dirs * np.where(hit, depth, 0.0)[..., None]
        xmin, zmin, xmax, zmax = self.scene.extent
        u = np.where(hit, (pos[..., 0] - xmin) / (xmax - xmin), np.nan)
        v = np.where(hit, (pos[..., 2] - zmin) / (zmax - zmin), np.nan)
        optical = np.zeros_like(depth)
        if self.haze is not None:
            ell = np.where(hit, depth, min(float(self.haze.sky_distance), far))
            optical = optical_length(m[1, 3], dirs, ell, ground=self.haze.ground, height=self.haze.height)
        return {
            "optical": optical,
            "depth": depth,
            "hit": hit,
            "id": lay["id"].astype(np.int64),
            "species": lay["species"].astype(np.int64),
            "dir": dirs,
            "u": u,
            "v": v,
        }

    # -- parameters ---------------------------------------------------------------------
    def set_lights(self, values: dict[str, np.ndarray]) -> None:
        """Light scales by parameter name (``sun_irradiance``, ``sky_zenith``, …); others keep theirs."""
        mi = self.mi
        for k, v in values.items():
            if k in self.scene.params:
                self.scene.params[k] = opaque(mi.Color3f, *np.asarray(v, np.float64).ravel()[:3])

    def set_sky_exponent(self, exponent: float) -> None:
        """The gradient sky's horizon band exponent k (:class:`~forest.render.path.inputs.SkyLight`); 1 is linear."""
        sky = self.inputs.sky
        if not self.gradient or sky is None:
            return
        k = float(exponent)
        self.inputs = self.scene.inputs = replace(self.inputs, sky=replace(sky, horizon_exponent=k))
        for light in self.scene.lights:
            if isinstance(light, SkyBasis):
                light.set_exponent(k)

    def set_haze(self, density: float) -> None:
        """The haze's ground extinction σ₀ (1/m); nothing without a haze."""
        if self.haze is not None:
            self.scene.params["haze_density"] = opaque(self.mi.Float, max(float(density), 0.0))

    def set_albedo(self, leaf_tint: np.ndarray, ground_tint: np.ndarray, grid: np.ndarray | None) -> None:
        """Set the (S, 3) leaf tints, the RGB ground tint and (when the scene has one) the colour grid."""
        mi = self.mi
        p = self.scene.params
        p["leaf_tint"] = mi.Float(mappable(np.asarray(leaf_tint, np.float32).ravel()))
        p["ground_tint"] = opaque(mi.Color3f, *np.asarray(ground_tint).ravel())
        if grid is not None and "colour_grid" in p:
            p["colour_grid"] = mi.TensorXf(mappable(np.asarray(grid, dtype=np.float32)))

    # -- images -------------------------------------------------------------------------
    def render(self, seed: int, spp: int | None = None) -> np.ndarray:
        """Linear RGB image (H, W, 3) of the current parameters with ``seed`` and ``spp`` (default the fit's)."""
        return np.asarray(self.scene.render(spp=spp or self.spp, seed=seed).rgb, np.float64)

    def light_images(self, seed: int, spp: int | None = None) -> dict[str, np.ndarray]:
        """U_k per light parameter: the image with light k at unit scale and every other light off."""
        mi = self.mi
        p = self.scene.params
        saved = {k: p[k] for k in self.light_params}
        out = {}
        try:
            for k in self.light_params:
                if k == "haze_colour" and float(np.asarray(p["haze_density"]).ravel()[0]) <= 0.0:
                    # No haze, no airlight: its image is black (and costs a render to learn it).
                    out[k] = np.zeros((self.height, self.width, 3))
                    continue
                for j in self.light_params:
                    p[j] = mi.Color3f(1.0) if j == k else mi.Color3f(0.0)
                out[k] = self.render(seed, spp)
        finally:
            for k, v in saved.items():
                p[k] = v
        return out

    def log_derivative(
        self, what: str, seed: int, *, species: int | None = None, tangent: np.ndarray | None = None
    ) -> np.ndarray:
        """∂I/∂ln m by forward-mode path replay; ``what``: ``leaves`` (all species, or ``species``), ``ground``,
        or ``grid`` (``tangent``: the (H, W, 3) change of the colour grid per unit ln-change of the cells)."""
        import drjit as dr

        mi = self.mi
        p = self.scene.params
        if what == "leaves":
            key = "leaf_tint"
            t = np.asarray(p[key], np.float64).reshape(-1, 3).copy()
            if species is not None:
                t[np.arange(len(t)) != species] = 0.0
            tan = mi.Float(mappable(t.astype(np.float32).ravel()))
        elif what == "ground":
            key = "ground_tint"
            tan = mi.Color3f(*[float(x) for x in np.asarray(p[key], np.float64).ravel()])
        elif what == "grid":
            key = "colour_grid"
            tan = mi.TensorXf(mappable(np.asarray(tangent, dtype=np.float32)))
        else:
            raise ValueError(what)
        value = p[key]
        dr.enable_grad(value)
        dr.set_grad(value, tan)
        try:
            d = self.scene.render_forward(spp=self.spp, seed=seed)
        finally:
            dr.disable_grad(value)
        return np.asarray(d, np.float64)
