"""Aerial perspective as a post-process, for the ``scalar_rgb`` renderer.

forest_path hazes every path segment (:mod:`forest.render.path.haze`); Mitsuba's
own integrators cannot, so the scalar renderer applies the same model to each
pixel's camera ray after the beauty is rendered:

    L' = L · T̄ + J(d) · (1 − T̄),    T̄ = a · T(ℓ_geo) + (1 − a) · T(ℓ_sky)

with d the pixel's central view direction, J the haze's source toward it
(ambient colour plus the sun through the Henyey–Greenstein phase), a the
pixel's coverage (the fraction of its camera samples that met geometry),
ℓ_geo the distance to the geometry at the pixel's centre and ℓ_sky the haze's
sky distance.  Splitting each pixel between its geometry and its sky by the
coverage keeps skylines clean: a pixel whose centre sees the sky but which a
thin silhouette (a ridge, a tree top) partly covers takes ℓ_geo from the
largest depth of its 3×3 neighbours, and its sky part is hazed like the sky —
no dark specks along the skyline.

Differences from forest_path, by design: secondary rays (bounce light between
surfaces) are not hazed, one depth stands for the whole pixel's geometry, and
the haze's light is not shadowed in either renderer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .path.haze import fog_anchor_np, source_np, transmittance_np

if TYPE_CHECKING:
    from ..config import Config
    from .path import PathCamera, PathScene


def pixel_directions(camera: PathCamera) -> np.ndarray:
    """(H, W, 3) unit world directions through the pixel centres of a ``PathCamera`` (pinhole, fov along x)."""
    w, h = int(camera.width), int(camera.height)
    t = np.tan(np.radians(float(camera.fov)) / 2.0)
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    x = (1.0 - 2.0 * j / w) * t  # camera +X is image left
    y = (1.0 - 2.0 * i / h) * t * h / w
    m = np.asarray(camera.to_world, np.float64)[:3, :3]
    d = np.stack([x, y, np.ones_like(x)], axis=-1) @ m.T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def apply_haze(
    rgb: np.ndarray, alpha: np.ndarray, depth: np.ndarray, camera: PathCamera, config: Config, path: PathScene
) -> np.ndarray:
    """The hazed beauty (see the module docstring).

    ``depth`` is the pixel-centre distance (the far clip where nothing is hit);
    ``camera`` the frame's ``PathCamera``; ``path`` the forest_path scene of the
    same frame, whose lights give the haze's default colour and its sun term.
    """
    from dataclasses import replace

    from scipy.ndimage import maximum_filter

    from .path.emitters import LightSet, luminance, sky_mean_radiance
    from .path.from_scene import haze_inputs

    haze = haze_inputs(config, path.inputs.terrain)
    if haze is None:
        return rgb
    if haze.colour is None:
        haze = replace(haze, colour=tuple(float(c) for c in sky_mean_radiance(path.lights)))
    sun = LightSet(path.mi, path.lights, path.params).sun()
    sun_direction = sun_irradiance = None
    if sun is not None:
        direction, irradiance_of, scale = sun
        e = irradiance_of(scale)
        sun_direction, sun_irradiance = direction, np.array([float(e[c][0]) for c in range(3)])
        if luminance(sun_irradiance) <= 0:
            sun_direction = sun_irradiance = None
    d = pixel_directions(camera)
    origin = np.asarray(camera.to_world, np.float64)[:3, 3]
    oy = float(origin[1])
    hit = depth < float(camera.far) * 0.999
    geo = np.where(hit, depth, 0.0)
    edge = ~hit & (alpha > 0) & (maximum_filter(hit.astype(np.uint8), size=3) > 0)
    geo = np.where(edge, maximum_filter(geo, size=3), geo)
    geo = np.where(hit | edge, geo, haze.sky_distance)
    a = np.clip(alpha, 0.0, 1.0)
    t_geo = transmittance_np(oy, d[..., 1], geo, haze, fog_anchor_np(origin, d, geo))
    t_sky = transmittance_np(oy, d[..., 1], haze.sky_distance, haze, fog_anchor_np(origin, d, haze.sky_distance))
    t = (a * t_geo + (1.0 - a) * t_sky)[..., None]
    j = source_np(d, haze, sun_direction, sun_irradiance)
    return (np.asarray(rgb, np.float64) * t + j * (1.0 - t)).astype(np.float32)
