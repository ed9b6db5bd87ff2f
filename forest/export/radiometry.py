"""Light units across renderers: forest's (Mitsuba's) sun and sky in RenderMan, USD and Blender terms.

forest describes its lights radiometrically, as Mitsuba does
(:func:`forest.render.scene.emitter_dicts`):

* the **sun** is a ``directional`` emitter of *irradiance* E (W/m² per unit
  colour) on a surface facing it;
* the **sky** is a ``constant`` emitter of *radiance* L (W/m²/sr per unit
  colour) from every direction of the sphere, or an ``envmap`` whose texels
  are radiances times ``scale``.

A Lambertian surface of albedo a lit by them reflects the radiance

    L_o = a/π · E · max(0, cos θ)  +  a/π · ∫ L cos θ dω  =  a/π · E cos θ  +  a · L · V

(θ the angle between the normal and the sun, V the unoccluded fraction of the
cosine-weighted hemisphere, 1 on open ground).  Each target states the same
lights in its own units; the functions below are those conversions, and the
tests check them against the integral above.

**RenderMan Shading Language (RI 3.2).**  ``diffuse(N)`` sums Cl · (N·L) over
the lights, without the 1/π of a Lambertian BRDF, and ``ambient()`` sums the Cl
of ambient lights.  A ``distantlight`` delivers Cl = intensity · lightcolor, so
with a surface shader ``Ci = a · (diffuse(Nf) + ambient())`` the sun's
intensity must be E/π (:func:`distantlight_intensity` — writing E itself makes
the sun π times too strong against the sky) and an ``ambientlight``'s intensity
is the sky radiance L itself (:func:`ambient_intensity`; its a·L is the
unoccluded term, V = 1).

**Area lights (RenderMan RIS ``PxrDistantLight``, ``UsdLuxDistantLight``).**
These emit a *radiance* L_s from a disk of angular diameter α (the sun: 0.53°).
The irradiance it gives a surface facing it is the cosine-weighted solid angle
of the cone of half-angle α/2 times L_s,

    E = L_s · π · sin²(α/2),

so the light's ``intensity`` is L_s = E / (π sin²(α/2))
(:func:`disk_radiance`) with normalisation off: about 14 900 · E for the sun,
44 650 for E = 3 W/m² — the order of RenderMan's default of 50 000.  A dome
(``PxrDomeLight``, ``UsdLuxDomeLight``) emits its intensity × colour as radiance,
so its intensity is L.

**Blender.**  A Sun lamp's *strength* is its irradiance in W/m² whatever its
angle, and the World background's colour × strength is a radiance: E and L
carry over unchanged (:func:`blender_sun_strength`).
"""

from __future__ import annotations

import math

#: Angular diameter of the sun seen from the earth, degrees.
SUN_ANGLE_DEG = 0.53


def distantlight_intensity(irradiance: float) -> float:
    """RI 3.2 ``distantlight`` intensity for a sun of irradiance E: E/π (see the module docstring)."""
    return float(irradiance) / math.pi


def ambient_intensity(radiance: float) -> float:
    """RI 3.2 ``ambientlight`` intensity for a constant sky of radiance L: L."""
    return float(radiance)


def disk_radiance(irradiance: float, angle_deg: float = SUN_ANGLE_DEG) -> float:
    """Radiance L_s of a disk of angular diameter α that gives irradiance E: E / (π sin²(α/2))."""
    if not 0.0 < angle_deg < 360.0:
        raise ValueError(f"angular diameter must be in (0, 360) degrees, got {angle_deg}")
    s = math.sin(math.radians(angle_deg) / 2.0)
    return float(irradiance) / (math.pi * s * s)


def disk_irradiance(radiance: float, angle_deg: float = SUN_ANGLE_DEG) -> float:
    """The inverse of :func:`disk_radiance`: E = L_s · π sin²(α/2)."""
    s = math.sin(math.radians(angle_deg) / 2.0)
    return float(radiance) * math.pi * s * s


def blender_sun_strength(irradiance: float) -> float:
    """Blender Sun lamp strength (W/m², irradiance) for a sun of irradiance E: E."""
    return float(irradiance)
