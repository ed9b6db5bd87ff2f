"""From a :class:`~.params.Look` to what the renderer and the camera model take.

The maps (all closed-form, so the optimiser differentiates them by finite
differences on a handful of scalars):

* the global horizontal irradiance G = G₀ · 2^light_level (G₀ the start's; ``light_level`` is
  fitted when the lights are, the camera's exposure then held — they are one degree of freedom);
* sun irradiance E_sun = share · G / sin(elevation) · c(T_sun, Duv_sun);
* gradient sky: Y_z = (1 − share)·G / (π − a_k + ρ·a_k), Y_h = ρ·Y_z (ρ = e^horizon_ratio,
  a_k = 2π/((k + 1)(k + 2)) for the horizon band exponent k, π/3 when linear),
  L_zenith = Y_z · c(T_z, Duv_z), L_horizon = Y_h · c(T_h, Duv_h) — so that the sky's
  horizontal irradiance (π − a_k)·Y_z + a_k·Y_h is (1 − share)·G; an environment map or
  ``sunsky`` sky keeps its shape and colour and its start scale is multiplied by
  (1 − share)·G / E_sky,0 (a sunsky's sun with it);
* camera gains W = c(T_wb, Duv_D(T_wb) + tint_wb) / c_D(6504 K) with unit luminance, times 2^EV (the
  balance moves along the daylight locus, Duv_D; the start, D65 with tint 0, is neutral);
* leaf tint of species s = exp(leaves + leaf_s) per channel; ground tint = exp(ground);
* haze colour (the haze's ambient radiance) = the start's ratio × L_horizon (× the sky's scale
  factor for an environment map or sunsky).

G₀ is the start's global horizontal irradiance (the gauge of :mod:`.params`),
c(T, Duv) the unit-luminance colour of :func:`.daylight.locus_rgb`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..render.path.emitters import horizon_irradiance
from .colour import luminance
from .daylight import D65_CCT, daylight_duv, daylight_rgb, locus_rgb
from .params import Look, Start

CHANNELS = "rgb"


@dataclass
class Lights:
    """Renderer light scales (linear RGB): the disc sun, and the sky as zenith/horizon or one scale."""

    sun: np.ndarray | None
    zenith: np.ndarray | None
    horizon: np.ndarray | None
    sky_scale: np.ndarray | None  # envmap / sunsky sky: RGB scale
    sun_scale: np.ndarray | None = None  # sunsky sun: RGB scale
    factor: float = 1.0  # envmap / sunsky: the scales over their start values


def _v(look: Look, name: str, default: float) -> float:
    return look.get(name, default)


def lights(look: Look, start: Start) -> Lights:
    """The light scales of ``look`` (see the module docstring)."""
    g = start.g0 * 2.0 ** _v(look, "light_level", 0.0)
    share = _v(look, "sun_share", start.share0) if start.sun_on else 0.0
    sun = None
    if start.sun_on:
        el = math.radians(start.sun_elevation)
        k = 1e6 / _v(look, "sun_mired", 1e6 / start.sun_kelvin)
        c = locus_rgb(k, _v(look, "sun_tint", start.sun_duv))
        y = share * g / max(math.sin(el), 1e-3) if g > 0 else start.sun_y
        sun = y * c
    zenith = horizon = scale = sun_scale = None
    factor = 1.0
    if start.sky_kind == "constant":
        tied = start.sky_tied
        rho = 1.0 if tied else math.exp(_v(look, "horizon_ratio", 0.0))
        e_sky = (1.0 - share) * g
        a = horizon_irradiance(start.sky_exponent)
        yz = e_sky / (math.pi - a + rho * a)
        hk = 1e6 / _v(look, "horizon_mired", 1e6 / start.sky_kelvin)
        sk = hk if tied else 1e6 / _v(look, "zenith_mired", 1e6 / start.sky_kelvin)
        zt = "horizon_tint" if tied else "zenith_tint"
        zenith = yz * locus_rgb(sk, _v(look, zt, start.sky_duv))
        horizon = rho * yz * locus_rgb(hk, _v(look, "horizon_tint", start.sky_duv))
    elif start.sky_kind in ("envmap", "sunsky"):
        factor = (1.0 - share) * g / start.sky_power if start.sky_power > 0 else 1.0
        scale = factor * start.initial.get("sky_scale", np.ones(3))
        if "sun_scale" in start.initial:
            sun_scale = factor * start.initial["sun_scale"]
    return Lights(sun, zenith, horizon, scale, sun_scale, factor)


def camera_gain(look: Look) -> np.ndarray:
    """2^EV · W: the per-channel gain from render to photo."""
    k = 1e6 / _v(look, "wb_mired", 1e6 / D65_CCT)
    # The balance moves along the daylight locus (tint: Duv off it), so the start (D65, 0) is exactly neutral.
    w = locus_rgb(k, float(daylight_duv(k)) + _v(look, "wb_tint", 0.0)) / daylight_rgb(D65_CCT)
    w = w / float(luminance(w))
    return (2.0 ** _v(look, "exposure", 0.0)) * w


def haze_colour(start: Start, lt: Lights) -> np.ndarray:
    """Airlight radiance: the horizon sky's times the start's ratio (the config's haze colour at the start)."""
    if lt.horizon is not None:
        return start.haze_ratio * lt.horizon
    return start.haze_ratio * (1.0 if lt.sky_scale is None else lt.sky_scale)


def leaf_tints(look: Look, n_species: int) -> np.ndarray:
    """(S, 3) multipliers of each species' leaf albedo."""
    common = np.array([_v(look, f"leaves_{c}", 0.0) for c in CHANNELS])
    out = np.empty((n_species, 3))
    for s in range(n_species):
        rel = np.array([_v(look, f"leaf{s}_{c}", 0.0) for c in CHANNELS])
        out[s] = np.exp(common + rel)
    return out


def ground_tint(look: Look) -> np.ndarray:
    """(3,) multiplier of the ground albedo: exp of the look's ``ground_r/g/b`` (1 where unset)."""
    return np.exp(np.array([_v(look, f"ground_{c}", 0.0) for c in CHANNELS]))
