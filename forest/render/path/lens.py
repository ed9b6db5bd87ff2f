"""Thin-lens camera rays: depth of field for forest_path.

A thin lens (Pharr, Jakob & Humphreys, *Physically Based Rendering*, 4th ed., §5.2.3; Kolb, Mitchell &
Hanrahan 1995, "A realistic camera model for computer graphics") of radius r, focused at distance z_f along
the view axis, images every point of the plane z = z_f sharply: all rays from one film point that cross the
lens meet again on that plane.  So a camera sample is built from the pinhole ray of its film point, origin c
(the camera's centre) and unit direction d:

* the point in focus: p_f = c + d · z_f / (d · ẑ), ẑ the view axis (the pinhole ray meets the plane z = z_f);
* a point on the lens: p_l = c + r·(u·x̂ + v·ŷ), (u, v) a uniform point of the unit disc drawn from the
  camera sample's own 2-D sample by the concentric mapping of Shirley & Chiu 1997 ("A low distortion map
  between disk and square": low distortion keeps a stratified sampler's strata compact on the disc);
* the ray: from p_l towards p_f, d' = (p_f − p_l) / |p_f − p_l|, clipped like the pinhole's — it starts at
  the near plane (t_n = near / (d' · ẑ)) and ends at the far plane (t_f = far / (d' · ẑ)).

This is the ray Mitsuba's ``thinlens`` sensor samples (``aperture_radius`` = r, ``focus_distance`` = z_f),
which ``scalar_rgb`` renders with.  With r = 0 every lens point is c and the ray is the pinhole's; the
renderer then skips this step altogether and draws no lens sample, so a pinhole render consumes exactly the
sampler dimensions it did before depth of field existed (byte-identical images).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .inputs import PathCamera


def thin_lens_rays(mi: Any, camera: PathCamera, ray: Any, lens_sample: Any) -> Any:
    """The thin-lens rays of ``camera`` for the pinhole rays ``ray`` (a ``mi.Ray3f`` from its ``perspective``
    sensor) and the lens samples ``lens_sample`` (``mi.Point2f`` in [0, 1)²): a new ``mi.Ray3f``."""
    import drjit as dr

    m = np.asarray(camera.to_world, np.float64)
    x_axis, y_axis, z_axis, centre = (mi.Vector3f(*[float(v) for v in m[:3, j]]) for j in range(4))
    r, z_f = float(camera.lens_radius), float(camera.focus_distance)
    focus = mi.Point3f(centre) + ray.d * (z_f / dr.dot(ray.d, z_axis))
    disc = mi.warp.square_to_uniform_disk_concentric(lens_sample)
    lens = mi.Point3f(centre) + x_axis * (r * disc.x) + y_axis * (r * disc.y)
    d = dr.normalize(focus - lens)
    inv_z = dr.rcp(dr.dot(d, z_axis))
    near_t, far_t = float(camera.near) * inv_z, float(camera.far) * inv_z
    out = mi.Ray3f(ray)
    out.o = lens + d * near_t
    out.d = d
    out.maxt = far_t - near_t
    return out
