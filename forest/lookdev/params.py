"""What look-dev fits: the parameters a photograph can pin down, their ranges and priors.

Every parameter lives in a *fit coordinate* in which its prior is Gaussian,
N(μ, σ²), and its physically plausible range is a box [lo, hi] the optimiser
never leaves.  The fit is a maximum a posteriori estimate: data residuals plus
(θ − μ)/σ for every parameter, so a parameter the reference says nothing about
stays at its prior instead of drifting along a flat direction of the loss.

**Camera** (group ``camera``) — the photo is P = 2^EV · W · H with H the render
after aerial perspective:

* ``exposure`` EV, range ±10 EV, prior N(0, 4²): a photo's exposure relative to
  the scene's light units is unknown; the prior only keeps the fit finite.
  The render is linear in its lights, so the camera's gain 2^EV · W and a common
  factor of every light are *one* thing, exactly (three degrees of freedom, one
  per channel).  A fit removes that degeneracy by construction: when any light is
  fitted (groups ``sun`` or ``sky``) the camera is held at neutral (0 EV, D65)
  and the lights carry the photo's brightness and colour cast — ``light_level``
  (EV of the global horizontal irradiance G over the start's) its brightness, the
  sun and sky colour temperatures its colour; only a fit without lights fits the
  camera, with G held at the start's.  The written scene folds 2^EV · W into the
  lights either way, so the two are the same look.
* ``white_balance`` mired (10⁶/T), the colour temperature the camera's
  balance leans to: W = c(T)/c(6504 K) normalised to unit luminance (von Kries
  gains on the daylight locus; c from :mod:`.daylight`), range 2500–12 000 K,
  prior N(6504 K, (25 mired)²) — auto white balance errs by a few hundred kelvin
  under daylight; ``wb_tint``: Duv offset from the daylight locus (green–magenta), prior N(0, 0.006²).

**Sun** (group ``sun``): direction from the config (not fitted from gradients);
``sun_mired``: the direct beam's colour temperature on the daylight locus
(Duv ``sun_tint`` with prior N(daylight Duv, 0.003²)), range 2000–10 000 K, prior
mean from the elevation — direct sunlight is ≈ 5500–5800 K with the sun high and
falls to ≈ 2000–3000 K near the horizon (Henderson 1977, *Daylight and its
Spectrum*, 2nd ed.; Wyszecki & Stiles 1982, §1.2) — σ = 60 mired;
``sun_share``: the sun's share of the global horizontal irradiance,
1 − k_d with k_d the diffuse fraction, range 0–0.95; clear skies give
k_d ≈ 0.1–0.25 and overcast skies k_d → 1 (Erbs, Klein & Duffie 1982,
*Solar Energy* 28: 293–302), prior N(start, 0.3²).

**Sky** (group ``sky``, a constant sky becomes the ``gradient`` sky of
:mod:`forest.render.path.emitters`, equal at the start): zenith and horizon
colours as colour temperatures with Duv (``zenith_mired``, ``zenith_tint``,
``horizon_mired``, ``horizon_tint``): clear-sky zenith light is ≈ 10 000–25 000 K
and more, overcast skies ≈ 6500–7500 K (Henderson 1977; CIE 15:2004 D-series),
priors N(12 000 K, (50 mired)²) and N(7000 K, (70 mired)²), Duv N(0, 0.01²);
``horizon_ratio`` = ln(Y_horizon/Y_zenith): ln(1/3) for the CIE overcast sky
(Moon & Spencer 1942; CIE S 011/E:2003 type 1), 0.5–1.1 for clear skies away
from the sun (ISO 15469 types 12–13), prior N(0, 0.8²), range [ln ¼, ln 6].
Sky radiances follow from G, ``sun_share`` and the ratio:
E_sky = π(Y_h + 2Y_z)/3 = (1 − share)·G.

**Leaves** (group ``leaves``): ``leaves_r/g/b`` ln-multipliers of every
species' leaf albedo (the PROSPECT-D colours of the library, Féret et al.
2017), prior N(0, 0.35²), range [ln ⅓, ln 3] and each channel's albedo within
0.005–0.8; ``leaf<s>_r/g/b`` a species' own ln-multiplier relative to the
others (sum over species 0), prior N(0, 0.25²).  A whole canopy seen from
above should end near measured canopy albedos (0.03–0.05 visible for conifer
stands, more for broadleaf; Betts & Ball 1997; forests 0.05–0.20 broadband,
Oke 1987, *Boundary Layer Climates*, Table 1.1).

**Ground** (group ``ground``): ``ground_r/g/b`` ln-multipliers of the terrain
albedo (one colour, a terrain map or the ``[ground]`` rules: the multiplier is
written as ``[lookdev] ground_tint``), prior N(0, 0.5²), the mean albedo within
0.02–0.6 per channel (soils 0.05–0.40, grass 0.16–0.26: Oke 1987, Table 1.1).

**Haze** (group ``haze``): the production haze's ground extinction σ₀ per metre
(:mod:`forest.render.path.haze`), range 0–0.004 (a meteorological visibility
V = 3.912/σ of 1 km and more, Koschmieder 1924), prior N(start, 0.0008²)
(V ≈ 5 km at 1σ); its ambient radiance follows the horizon sky's (airlight tends
to the horizon radiance at large distance, Koschmieder) times the start's ratio.

When the sky seen in the frame reaches less than :data:`GRADIENT_MIN_ELEVATION` above
the horizon, a gradient linear in μ would be fitted from a sliver of it and
extrapolated to the zenith, where its brightness trades against the albedos.  The
gradient's horizon colour is then a band, weight b = (1 − μ)^k, whose exponent k puts
b = :data:`HORIZON_BAND_AT_TOP` at the top of the visible sky
(:func:`horizon_band_exponent`): the horizon colour is what the frame shows along
the horizon (the glow of a low sun, haze), the "zenith" colour what it shows above
the band, taken to hold up to the zenith — no extrapolation beyond the frame's sky.
With no sky in frame the sky is fitted as one colour (zenith = horizon,
``sky_tied``) and the gradient reported as held.

**Colour map** (group ``colour_map``, aligned mode): an ln-correction per cell of
:mod:`.correction`, with an edge-preserving prior (``map_prior = "edges"``, the
default) or the smooth field of earlier versions (``"smooth"``); see
:mod:`.solve`.

**Anchor.**  Albedos and lights trade too: an image is (to first order, exactly for
singly scattered light) the product of an albedo and an irradiance, so every albedo
×a and every light ÷a per channel renders nearly the same picture — only the sky seen
directly and multiply scattered light tell them apart.  The *anchor* fixes that
scale by holding one side at what the scene says (:data:`ANCHORS`): ``ground`` (the
ground's albedo, from the scene's ground rules — the default in aligned mode when the
frame shows ground), ``leaves`` (the species' measured leaf colours; the colour map's
mean with them), ``lights`` (the light level of the config) or ``none`` (the priors
decide — the default in statistics mode, where another place's ground says nothing
about the scene's).  Where a degeneracy remains, :func:`.solve.weak_directions`
names it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .daylight import D65_CCT, daylight_duv, mired

#: Highest elevation (degrees) the visible sky must reach for its gradient to be fitted linear in μ.
GRADIENT_MIN_ELEVATION = 30.0
#: Weight of the horizon colour at the top of the frame's sky when the sky is fitted as a horizon band.
HORIZON_BAND_AT_TOP = 0.1
GROUPS = ("camera", "sun", "sky", "leaves", "ground", "haze", "colour_map")
#: What holds the scale of albedos against light (see the module docstring); ``auto`` picks per mode.
ANCHORS = ("auto", "ground", "leaves", "lights", "none")
#: The colour map's prior: edge-preserving cells, or the smooth correction field of earlier versions.
MAP_PRIORS = ("edges", "smooth")
#: Light groups: fitting any of them holds the camera (its gain is a common factor of the lights).
LIGHT_GROUPS = ("sun", "sky")
#: What a fit varies when ``--params`` is not given, by mode.
DEFAULT_GROUPS = {
    "aligned": ("camera", "sun", "sky", "leaves", "ground", "haze", "colour_map"),
    "statistics": ("camera", "sun", "sky", "leaves", "ground", "haze"),
}
LN = math.log

#: Direct-beam colour temperature of the sun against its elevation (degrees → K), after
#: Henderson (1977) and Wyszecki & Stiles (1982): a prior mean, not a model.
SUN_CCT_BY_ELEVATION = (
    (0.0, 2000.0),
    (5.0, 3000.0),
    (10.0, 3800.0),
    (20.0, 4600.0),
    (30.0, 5100.0),
    (45.0, 5500.0),
    (60.0, 5800.0),
    (90.0, 5800.0),
)


def _mired(kelvin: float) -> float:
    """10⁶ / T as a float."""
    return float(mired(kelvin))


def horizon_band_exponent(top: float) -> float:
    """k with (1 − top)^k = :data:`HORIZON_BAND_AT_TOP` for a frame whose sky reaches μ = ``top`` (sine of its
    elevation): 1 (linear) from :data:`GRADIENT_MIN_ELEVATION` up, at most 1000 (a sky a few arc-minutes high)."""
    if top >= math.sin(math.radians(GRADIENT_MIN_ELEVATION)):
        return 1.0
    t = min(max(float(top), 1e-4), 1.0)
    return float(min(max(math.log(HORIZON_BAND_AT_TOP) / math.log1p(-t), 1.0), 1000.0))


def sun_prior_kelvin(elevation: float) -> float:
    """Prior mean of the sun's colour temperature at ``elevation`` degrees."""
    e, t = zip(*SUN_CCT_BY_ELEVATION)
    return float(np.interp(max(float(elevation), 0.0), e, t))


@dataclass(frozen=True)
class Spec:
    """One fitted scalar: fit coordinate, range, prior, and how to show it."""

    name: str
    group: str
    label: str  # what an artist reads
    lo: float
    hi: float
    mean: float
    sigma: float
    unit: str = ""
    kind: str = "plain"  # "plain" | "mired" (shown in K) | "log" (shown as a multiplier)
    #: What the lower bound means when it is a physical limit rather than a plausible range's end (a parameter
    #: there is a look, not a failure: "clear air"), or "" when it is a range's end.
    natural_lo: str = ""

    def show(self, value: float) -> str:
        """``value`` (a fit coordinate) as an artist reads it: mireds as kelvin, logs as a multiplier, with its unit."""
        if self.kind == "mired":
            return f"{1e6 / value:,.0f} K"
        if self.kind == "log":
            return f"×{math.exp(value):.3f}"
        if self.unit == "EV":
            return f"{value:+.2f} EV"
        return f"{value:.4g}{(' ' + self.unit) if self.unit else ''}"

    def show_range(self) -> str:
        """The range [lo, hi] shown as :meth:`show` shows a value."""
        if self.kind == "mired":
            return f"{1e6 / self.hi:,.0f}–{1e6 / self.lo:,.0f} K"
        if self.kind == "log":
            return f"×{math.exp(self.lo):.2f}–×{math.exp(self.hi):.2f}"
        return f"{self.lo:g}–{self.hi:g}{(' ' + self.unit) if self.unit else ''}"


@dataclass
class Start:
    """What the config says: the start of the fit and the gauges it keeps."""

    sun_elevation: float
    sun_azimuth: float
    sun_on: bool  # a disc sun above the horizon
    sun_y: float  # luminance of the sun's irradiance (E·Y(c))
    sun_kelvin: float
    sun_duv: float
    sky_kind: str | None  # "constant" (fitted as a gradient) | "envmap" | "sunsky" | None
    sky_rgb: np.ndarray  # constant sky radiance (RGB), zeros otherwise
    sky_power: float  # the sky's horizontal irradiance (luminance) at the start
    sky_kelvin: float
    sky_duv: float
    haze: float
    haze_ratio: np.ndarray  # haze radiance / horizon radiance at the start (per channel)
    terrain_colour: np.ndarray  # the ground's albedo (its mean over a terrain map), RGB
    leaf_colours: np.ndarray  # (S, 3) mean leaf colour per species (for albedo bounds)
    species: list[str]
    has_haze: bool = False  # the fit renders a haze (its density and colour can change)
    initial: dict[str, np.ndarray] = field(default_factory=dict)  # each light parameter's start value (RGB)
    ground_tint0: np.ndarray = field(default_factory=lambda: np.ones(3))  # the config's ground tint
    leaf_tint0: np.ndarray | None = None  # (S, 3) the config's leaf tints
    sky_tied: bool = False  # no sky in frame: one colour, zenith = horizon
    sky_exponent: float = 1.0  # the gradient's horizon band exponent k (1: linear in μ)

    @property
    def g0(self) -> float:
        """The gauge: global horizontal irradiance (luminance) of the start."""
        return self.sun_y * max(math.sin(math.radians(self.sun_elevation)), 0.0) * self.sun_on + self.sky_power

    @property
    def share0(self) -> float:
        """The sun's share of :attr:`g0` at the start (0 without light)."""
        g = self.g0
        return (
            0.0
            if g <= 0
            else float(self.sun_y * max(math.sin(math.radians(self.sun_elevation)), 0.0) * self.sun_on / g)
        )


def specs_for(start: Start, groups: set[str]) -> list[Spec]:
    """The global parameters of a fit (grid cells are separate), with ranges and priors for this start."""
    out: list[Spec] = []
    if groups & set(LIGHT_GROUPS) and (start.sun_on or start.sky_kind is not None):
        # The lights' common level (the camera's exposure is held: they are one degree of freedom).
        out.append(Spec("light_level", "lights", "light level (sun and sky)", -10.0, 10.0, 0.0, 4.0, "EV"))
    if "camera" in groups:
        out += [
            Spec("exposure", "camera", "camera exposure", -10.0, 10.0, 0.0, 4.0, "EV"),
            Spec(
                "wb_mired",
                "camera",
                "camera white balance",
                _mired(12000.0),
                _mired(2500.0),
                _mired(D65_CCT),
                25.0,
                kind="mired",
            ),
            Spec("wb_tint", "camera", "camera tint (Duv)", -0.02, 0.02, 0.0, 0.006),
        ]
    if "sun" in groups and start.sun_on:
        prior_k = sun_prior_kelvin(start.sun_elevation)
        m0 = float(np.clip(_mired(start.sun_kelvin), _mired(10000.0), _mired(2000.0)))
        out += [
            Spec(
                "sun_mired",
                "sun",
                "sun colour temperature",
                _mired(10000.0),
                _mired(2000.0),
                _mired(prior_k),
                60.0,
                kind="mired",
            ),
            Spec("sun_tint", "sun", "sun tint (Duv)", -0.02, 0.02, float(daylight_duv(1e6 / m0)), 0.003),
            Spec(
                "sun_share",
                "sun",
                "sun share of the irradiance",
                0.0,
                0.95,
                min(start.share0, 0.95),
                0.3,
                natural_lo="no direct sun (an overcast sky)",
            ),
        ]
    if "sky" in groups and start.sky_kind == "constant" and start.sky_tied:
        out += [
            Spec(
                "horizon_mired",
                "sky",
                "sky colour temperature",
                _mired(40000.0),
                _mired(1800.0),
                _mired(9000.0),
                70.0,
                kind="mired",
            ),
            Spec("horizon_tint", "sky", "sky tint (Duv)", -0.03, 0.03, 0.0, 0.01),
        ]
    elif "sky" in groups and start.sky_kind == "constant":
        out += [
            Spec(
                "zenith_mired",
                "sky",
                "sky zenith colour temperature",
                _mired(40000.0),
                _mired(2500.0),
                _mired(12000.0),
                50.0,
                kind="mired",
            ),
            Spec("zenith_tint", "sky", "sky zenith tint (Duv)", -0.03, 0.03, 0.0, 0.01),
            Spec(
                "horizon_mired",
                "sky",
                "sky horizon colour temperature",
                _mired(40000.0),
                _mired(1800.0),
                _mired(7000.0),
                70.0,
                kind="mired",
            ),
            Spec("horizon_tint", "sky", "sky horizon tint (Duv)", -0.03, 0.03, 0.0, 0.01),
            Spec("horizon_ratio", "sky", "sky horizon / zenith luminance", LN(0.25), LN(6.0), 0.0, 0.8, kind="log"),
        ]
    if "haze" in groups and start.has_haze:
        out.append(
            Spec(
                "haze",
                "haze",
                "haze extinction",
                0.0,
                0.004,
                start.haze,
                0.0008,
                "1/m",
                natural_lo="no haze (clear air)",
            )
        )
    if "leaves" in groups and len(start.species):
        mean_c = start.leaf_colours.mean(axis=0)
        for c, ch in enumerate("rgb"):
            lo = max(LN(1 / 3), LN(0.005 / max(mean_c[c], 1e-6)))
            hi = min(LN(3.0), LN(0.8 / max(mean_c[c], 1e-6)))
            out.append(
                Spec(f"leaves_{ch}", "leaves", f"leaf colour {ch}", lo, max(hi, lo + 1e-3), 0.0, 0.35, kind="log")
            )
        if len(start.species) > 1:
            for s, name in enumerate(start.species):
                for ch in "rgb":
                    out.append(
                        Spec(
                            f"leaf{s}_{ch}",
                            "leaves",
                            f"{name} leaves {ch} (relative)",
                            LN(0.5),
                            LN(2.0),
                            0.0,
                            0.25,
                            kind="log",
                        )
                    )
    if "ground" in groups:
        for c, ch in enumerate("rgb"):
            tc = max(float(start.terrain_colour[c]), 1e-6)
            lo, hi = max(LN(0.25), LN(0.02 / tc)), min(LN(4.0), LN(0.6 / tc))
            out.append(
                Spec(f"ground_{ch}", "ground", f"ground colour {ch}", lo, max(hi, lo + 1e-3), 0.0, 0.5, kind="log")
            )
    return out


def start_values(start: Start, specs: list[Spec]) -> dict[str, float]:
    """The fit coordinates of the config's own look (exactly what it renders)."""
    v: dict[str, float] = {}
    for s in specs:
        if s.name == "sun_mired":
            v[s.name] = float(np.clip(_mired(start.sun_kelvin), s.lo, s.hi))
        elif s.name == "sun_tint":
            v[s.name] = float(np.clip(start.sun_duv, s.lo, s.hi))
        elif s.name == "sun_share":
            v[s.name] = float(np.clip(start.share0, s.lo, s.hi))
        elif s.name in ("zenith_mired", "horizon_mired"):
            v[s.name] = float(np.clip(_mired(start.sky_kelvin), s.lo, s.hi))
        elif s.name in ("zenith_tint", "horizon_tint"):
            v[s.name] = float(np.clip(start.sky_duv, s.lo, s.hi))
        elif s.name == "wb_mired":
            v[s.name] = float(_mired(D65_CCT))
        elif s.name == "haze":
            v[s.name] = float(np.clip(start.haze, s.lo, s.hi))
        else:
            v[s.name] = float(np.clip(0.0, s.lo, s.hi))
    return v


@dataclass
class Look:
    """A point of the fit: global values by name (fit coordinates) and the colour-map ln-correction."""

    values: dict[str, float]
    correction: np.ndarray | None = None  # (n, m, 3) ln-correction cells, or None
    held: dict[str, float] = field(default_factory=dict)  # parameters held at these values

    def copy(self) -> Look:
        """An independent copy (values, held values and correction copied)."""
        return Look(dict(self.values), None if self.correction is None else self.correction.copy(), dict(self.held))

    def get(self, name: str, default: float = 0.0) -> float:
        """The value of parameter ``name``, free or held; ``default`` when the look has neither."""
        if name in self.values:
            return float(self.values[name])
        return float(self.held.get(name, default))
