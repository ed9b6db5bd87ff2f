"""The look being fitted, and how it is parametrised so that it is identifiable.

What a pixel of a diffuse forest sees is, to first order,

    I = ρ_part · m(x) · ( E_sun · c_sun · V_sun cos θ / π  +  L_sky · c_sky · V_sky )

with m the colour map (a multiplier of each tinted part's base colour ρ_part;
the terrain is tinted by the same map), E·c the sun's irradiance and L·c the
sky's radiance.  That product has **scale ambiguities**: (E, L, m) and
(kE, kL, m/k) render the same image, and so do per-channel scalings of both
light colours against the map's colour.  Three choices make the problem
identifiable:

1. **Colours are chromaticities.**  Light colours are kept at unit CIE
   luminance, Y(c) = 0.2126 r + 0.7152 g + 0.0722 b = 1, and the intensity
   lives in one scalar (E, L, or an environment map's scale).  Fitting
   optimises a free positive 3-vector c̃ and uses c = c̃ / Y(c̃), so the
   luminance gauge is exact; intensities are optimised as logarithms (positive,
   and Adam's steps become relative).
2. **The sky is the anchor.**  Where the camera sees the sky directly, its
   pixels are L·c_sky with no reflectance in between, which fixes L and c_sky
   absolutely; shadowed ground and foliage then fix the map, and sunlit
   surfaces the sun.  When less than :data:`MIN_SKY_FRACTION` of the frame
   shows the sky, the sky is held at its current value (a warning says so)
   and only the map and sun are fitted: the gauge is then the sky.
3. **The map is a multiplier in [0, 1]** (white = the part's own colour), as
   the production renderer uses it.  In ``statistics`` mode, where an
   unrelated photo cannot place colours, the map keeps its spatial pattern
   and a single global tint t (3 values) is fitted: m' = min(t·m₀, 1).

Written back into a config, the sun's ``colour`` therefore has unit
luminance and ``irradiance`` carries its strength (the product — what the
renderer uses — is what was fitted), and likewise for the sky.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from .colour import luminance

MIN_SKY_FRACTION = 0.005
PARAM_GROUPS = ("colour_map", "sun", "sky", "sun_direction")
DEFAULT_PARAMS = ("colour_map", "sun", "sky")


def split_colour(intensity: float, colour) -> tuple[float, np.ndarray]:
    """(s, c) → (s·Y(c), c / Y(c)): the same product with a unit-luminance colour."""
    c = np.asarray(colour, dtype=np.float64)
    y = float(luminance(c))
    if y <= 1e-12:
        return 0.0, np.ones(3)
    return float(intensity) * y, c / y


@dataclass
class LookState:
    """One look: colour grid, sun and sky (numpy, the optimiser's readable side)."""

    grid: np.ndarray  # (n, m, 3) in [0, 1], map convention
    sun_irradiance: float | None = None  # E (W/m²), colour has unit luminance
    sun_colour: np.ndarray | None = None
    sun_elevation: float | None = None
    sun_azimuth: float | None = None
    sky_kind: str | None = None  # "constant" | "envmap" | "sunsky" | None
    sky_radiance: float | None = None
    sky_colour: np.ndarray | None = None
    envmap_scale: float | None = None
    tint: np.ndarray = field(default_factory=lambda: np.ones(3))  # statistics mode

    def copy(self) -> LookState:
        return copy.deepcopy(self)

    def config_overrides(self) -> dict:
        """The light values as scene-file overrides (:func:`forest.config.apply_overrides`)."""
        o: dict = {}
        if self.sun_irradiance is not None:
            o["lights.sun.irradiance"] = float(self.sun_irradiance)
            o["lights.sun.colour"] = [float(x) for x in self.sun_colour]
        if self.sun_elevation is not None:
            o["lights.sun.elevation"] = float(self.sun_elevation)
            o["lights.sun.azimuth"] = float(self.sun_azimuth)
        if self.sky_kind == "constant":
            o["lights.sky.radiance"] = float(self.sky_radiance)
            o["lights.sky.colour"] = [float(x) for x in self.sky_colour]
        elif self.sky_kind == "envmap":
            o["lights.sky.scale"] = float(self.envmap_scale)
        elif self.sky_kind == "sunsky":
            o["lights.sky.sunsky.scale"] = float(self.envmap_scale)
        return o

    def light_values(self) -> dict[str, float]:
        """Scalar light figures by name (for trajectories and reports)."""
        v: dict[str, float] = {}
        if self.sun_irradiance is not None:
            v["sun irradiance"] = float(self.sun_irradiance)
            for ch, x in zip("rgb", self.sun_colour):
                v[f"sun colour {ch}"] = float(x)
        if self.sun_elevation is not None:
            v["sun elevation"] = float(self.sun_elevation)
            v["sun azimuth"] = float(self.sun_azimuth)
        if self.sky_kind == "constant":
            v["sky radiance"] = float(self.sky_radiance)
            for ch, x in zip("rgb", self.sky_colour):
                v[f"sky colour {ch}"] = float(x)
        elif self.envmap_scale is not None:
            v["sky scale"] = float(self.envmap_scale)
        return v

    def sun_rgb(self) -> np.ndarray | None:
        return None if self.sun_irradiance is None else self.sun_irradiance * np.asarray(self.sun_colour)

    def sky_rgb(self) -> np.ndarray | None:
        return None if self.sky_kind != "constant" else self.sky_radiance * np.asarray(self.sky_colour)


def state_from_config(config, grid: np.ndarray) -> LookState:
    """The config's current look, with light colours split into unit-luminance chromaticities."""
    lights = config.lights
    st = LookState(grid=np.clip(np.asarray(grid, dtype=np.float64), 0.0, 1.0))
    sun, sky = lights.sun, lights.sky
    if sun is not None:
        st.sun_irradiance, st.sun_colour = split_colour(sun.irradiance, sun.colour)
        st.sun_elevation, st.sun_azimuth = float(sun.elevation), float(sun.azimuth)
    if sky is not None:
        st.sky_kind = sky.kind
        if sky.kind == "constant":
            st.sky_radiance, st.sky_colour = split_colour(sky.radiance, sky.colour)
        elif sky.kind == "envmap":
            st.envmap_scale = float(sky.scale)
        else:
            st.envmap_scale = float(sky.sunsky.scale)
    if sky is not None and sky.kind == "sunsky":
        st.sun_irradiance = st.sun_colour = None  # sunsky's sun follows its scale
    return st
