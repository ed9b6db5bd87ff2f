"""The lights, resolved once from ``[lights]``: the sun and sky every renderer and exporter reads.

**Directions.**  Y is up; an azimuth A is measured clockwise from +Z (north)
towards +X (east) and an elevation E above the horizon, in degrees.  The unit
vector from the ground towards the sun is

    s = (sin A cos E,  sin E,  cos A cos E)                                    (1)

(:func:`sun_vector`); a directional light shines along −s.

**One rule for "is the sun on".**  Before this module each backend decided for
itself (the scalar renderer, forest_path, RIB, USD, Blender and look-dev each
had their own test).  Here:

* :attr:`Lights.sun` is the sun that lights the scene: ``[lights.sun]`` when its
  elevation and irradiance are both above zero, else None (a sun at or below the
  horizon lights nothing).
* A ``sunsky`` sky is Mitsuba's Hosek–Wilkie sky *and sun* pointed at
  ``[lights.sun]`` — or, without one, at the default sun (35° high, azimuth 120°,
  3 W/m², :data:`DEFAULT_SUN`) — and scaled so its sun sends that sun's
  irradiance (:attr:`Sky.sun` is the sun it is pointed at, below the horizon
  too).  Renderers with the sky model (Mitsuba's ``sunsky``, forest_path) draw
  the model's own sun and so skip :attr:`Lights.sun`; exporters, whose targets
  have no Hosek–Wilkie model, write :attr:`Lights.sun` as a distant light and the
  sky as a dome (:meth:`Sky.dome`).
* A ``constant`` sky has radiance ``radiance × colour``; an ``envmap`` sky is
  the latitude–longitude image (+Y up) times ``scale``; an ``hdri`` sky is an
  ``envmap`` sky whose image ships with forest (:mod:`forest.hdri`).
* **The sun of a map** (``map_sun``, on by default for an ``hdri``): the sun is
  found in the image, taken out of it (its pixels refilled with the surrounding
  sky's level) and becomes :attr:`Lights.sun` — a disc sun in its direction with
  the irradiance and colour it had in the map, times ``scale``
  (:func:`forest.hdri.split_sun`; :attr:`Sky.envmap` is then the processed
  image, cached on disk, and :attr:`Sky.source` the original).  A path tracer
  samples a half-degree disc far better than a few very bright texels (no
  fireflies), and the sharp shadows agree with the map.  A ``[lights.sun]``
  given in the config wins: it lights the scene, and the map's sun is still
  taken out (otherwise two suns would light it).  Done here, once, so every
  backend — forest_path, ``scalar_rgb`` and the exporters' dome lights — sees
  the same map and sun.

* ``[lights.clouds]`` lays a procedural cloud layer over the sky (:class:`Clouds`;
  forest_path only — Mitsuba's own integrator in ``scalar_rgb`` has no such sky and
  renders the clear sky with a warning; exporters ignore it).

The Scene carries the result (``scene.lights``); functions that have only a
config call :func:`resolve_lights`, the same rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from .errors import ConfigError, ForestError

RGB = tuple[float, float, float]

#: The dome exporters stand in for a physical sun-sky with: intensity 0.35 × ``sunsky.scale``, a neutral blue.
SUNSKY_DOME: tuple[float, RGB] = (0.35, (0.6, 0.75, 1.0))


def sun_vector(elevation: float, azimuth: float) -> np.ndarray:
    """Unit vector towards the sun, equation (1): (sin A cos E, sin E, cos A cos E); degrees in."""
    e, a = math.radians(elevation), math.radians(azimuth)
    return np.array([math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e)])


@dataclass(frozen=True)
class Sun:
    """A sun: its position in the sky (degrees), irradiance facing it (W/m² per unit colour) and linear RGB colour."""

    elevation: float
    azimuth: float
    irradiance: float
    colour: RGB

    @property
    def direction(self) -> np.ndarray:
        """Unit vector from the ground towards the sun, equation (1)."""
        return sun_vector(self.elevation, self.azimuth)

    @property
    def rgb(self) -> np.ndarray:
        """Irradiance per RGB channel facing the sun: ``irradiance × colour`` (float64)."""
        return float(self.irradiance) * np.asarray(self.colour, dtype=np.float64)

    @property
    def lit(self) -> bool:
        """True when the sun is above the horizon and sends light."""
        return self.elevation > 0 and self.irradiance > 0


#: The sun a ``sunsky`` sky points at when the config has no ``[lights.sun]`` (the schema's defaults).
DEFAULT_SUN = Sun(elevation=35.0, azimuth=120.0, irradiance=3.0, colour=(1.0, 0.95, 0.88))


@dataclass(frozen=True)
class Sky:
    """A sky: ``constant`` (``intensity × colour`` radiance), ``envmap`` (``envmap`` × ``intensity``) or
    ``sunsky`` (Hosek–Wilkie, pointed at and normalised to ``sun``, times ``intensity``).

    ``intensity`` is the constant sky's ``radiance``, the environment map's ``scale`` or the sun-sky's
    ``scale``; ``colour`` is the constant sky's (white otherwise).  For an environment map whose sun was
    taken out (``map_sun``), ``envmap`` is the processed image, ``source`` the original one and
    ``map_sun`` the sun found in it (irradiance × ``scale``), whether or not it lights the scene.
    """

    kind: Literal["constant", "envmap", "sunsky"]
    intensity: float = 1.0
    colour: RGB = (1.0, 1.0, 1.0)
    envmap: Path | None = None
    turbidity: float = 3.0
    albedo: float = 0.15
    sun: Sun | None = None
    source: Path | None = None
    map_sun: Sun | None = None
    background: Literal["map", "sunsky"] = "map"

    @property
    def radiance(self) -> np.ndarray:
        """A constant sky's radiance per RGB channel, ``intensity × colour`` (float64)."""
        return float(self.intensity) * np.asarray(self.colour, dtype=np.float64)

    def dome(self) -> tuple[float, RGB]:
        """(intensity, colour) of a dome light for renderers without the sky model.

        A constant sky is itself; an environment map is its ``scale`` over white (the image gives the
        colour); a sun-sky is the neutral blue stand-in :data:`SUNSKY_DOME` times its ``scale``.
        """
        if self.kind == "sunsky":
            return SUNSKY_DOME[0] * float(self.intensity), SUNSKY_DOME[1]
        return float(self.intensity), self.colour


@dataclass(frozen=True)
class Clouds:
    """A cloud layer in the sky (:mod:`forest.render.path.clouds`): a fraction ``cover`` of the sky covered,
    on a plane ``altitude`` metres up, clouds about ``scale`` metres across, optical thickness up to about
    3 × ``density``, edges ``softness`` wide (noise units), the pattern from ``seed`` and slid by ``wind``
    (x, z metres); camera rays see cumulus up to ``height`` metres tall above the plane (None: 0.4 ×
    ``scale``; 0: the flat layer); ``clustering`` gathers the clouds into groups with clear sky between and
    varies their heights (0: evenly spread, all as tall)."""

    cover: float = 0.4
    altitude: float = 2000.0
    scale: float = 800.0
    seed: int = 0
    density: float = 4.0
    softness: float = 0.12
    wind: tuple[float, float] = (0.0, 0.0)
    height: float | None = None
    clustering: float = 0.5


@dataclass(frozen=True)
class Lights:
    """The sun that lights the scene (None when off), the sky (None without one) and its clouds (None
    without); see the module docstring."""

    sun: Sun | None
    sky: Sky | None
    clouds: Clouds | None = None

    @property
    def sunsky(self) -> bool:
        """True when the sky is the physical sun-sky, whose model draws the sun itself."""
        return self.sky is not None and self.sky.kind == "sunsky"

    def require(self, path) -> Lights:
        """These lights, or a :class:`~forest.errors.ConfigError` on ``lights`` of config file ``path`` when
        nothing lights the scene (no sky and the sun off)."""
        if self.sun is None and self.sky is None:
            raise ConfigError(
                path,
                "lights",
                "no light left (the sun is at or below the horizon, or sends nothing, and there is no sky)",
            )
        return self


def _sun(cfg) -> Sun:
    r, g, b = (float(c) for c in cfg.colour)
    return Sun(float(cfg.elevation), float(cfg.azimuth), float(cfg.irradiance), (r, g, b))


def _envmap_sky(config, k) -> Sky:
    """An ``envmap`` or ``hdri`` sky, its sun taken out of the map when ``map_sun`` says so (module docstring)."""
    from .hdri import sky_path, split_sun

    path = sky_path(k.hdri) if k.hdri is not None else Path(k.envmap)
    scale, rotation = float(k.scale), float(k.rotation)
    if not k.splits_sun and rotation == 0.0:
        return Sky("envmap", scale, envmap=path, background=k.background)
    try:
        split = split_sun(path, rotation=rotation, take_sun=k.splits_sun)
    except (ForestError, OSError) as e:
        field = "lights.sky.hdri" if k.hdri is not None else "lights.sky.envmap"
        raise ConfigError(config.path, field, getattr(e, "message", None) or str(e)) from None
    map_sun = None
    if split.elevation is not None and split.azimuth is not None:
        map_sun = Sun(split.elevation, split.azimuth, split.irradiance * scale, split.colour)
    return Sky("envmap", scale, envmap=split.path, source=path, map_sun=map_sun, background=k.background)


def resolve_lights(config) -> Lights:
    """``config.lights`` as :class:`Lights`, by the rules of the module docstring."""
    cfg = config.lights
    sun = _sun(cfg.sun) if cfg.sun is not None else None
    sky = None
    k = cfg.sky
    if k is not None:
        if k.kind == "sunsky":
            sun = sun if sun is not None else DEFAULT_SUN
            ss = k.sunsky
            sky = Sky("sunsky", float(ss.scale), turbidity=float(ss.turbidity), albedo=float(ss.albedo), sun=sun)
        elif k.kind == "envmap":
            sky = _envmap_sky(config, k)
            if sun is None:  # no [lights.sun]: the map's own sun lights the scene
                sun = sky.map_sun
        else:
            r, g, b = (float(c) for c in k.colour)
            sky = Sky("constant", float(k.radiance), (r, g, b))
    clouds = None
    c = getattr(cfg, "clouds", None)
    if c is not None and sky is not None and float(c.cover) > 0.0:
        clouds = Clouds(
            float(c.cover),
            float(c.altitude),
            float(c.scale),
            int(c.seed),
            float(c.density),
            float(c.softness),
            (float(c.wind[0]), float(c.wind[1])),
            None if c.height is None else float(c.height),
            float(c.clustering),
        )
    return Lights(sun=sun if sun is not None and sun.lit else None, sky=sky, clouds=clouds)
