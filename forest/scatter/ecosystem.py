"""The ecosystem survival rule: plants placed by competition and self-thinning.

In the spirit of Deussen et al. 1998 ("Realistic modeling and rendering of
plant ecosystems", §3): every plant is a circle — its zone of influence — that
grows; where two circles overlap the weaker plant dies.  Selected as
``[scatter] method = "ecosystem"``; it runs on the candidates that passed the
shared rules (:mod:`forest.scatter.candidates`: presence, density, species by
``percent`` read as relative seeding rates, partitions, and the hard slope and
altitude windows), all steps vectorised over plants:

* **Site fitness** f ∈ [0, 1] per seed: a soft preference for moisture,
  1 inside the species' ``moisture = [lo, hi]`` and a Gaussian shoulder
  exp(−½ (δ/0.1)²) at a distance δ outside it.  Moisture comes from
  ``[maps] moisture`` or, without a map, from the terrain: low and flat
  ground is wet, m = (1 − ĥ)(1 − θ/90°) with ĥ the normalised height and θ
  the slope.  (Slope and altitude enter as the shared hard windows, not as
  preferences: a preference of this shape is 1 everywhere inside its window.)
  Seeds with f < ``[ecosystem] establish`` never establish (stage ``site``).
* **Growth** — over ``steps`` years, radius r(t) = R·f·(1 − e^(−g t)) with the
  species' mature ``radius`` R (m) and ``growth`` rate g (1/yr).
* **Competition** — each year, every pair of living plants with
  r_i + r_j > d_ij (found with a KD-tree) is resolved at once: the plant with
  the larger r·vigour wins (ties: the earlier seed) and the other dies (stage
  ``competition``) — unless the loser is **shade tolerant**
  (``shade_tolerance`` ≥ 0.5) and its own mature radius is under half the
  winner's: undergrowth survives beneath a canopy and ages only half a year
  that year, so it grows more slowly.
* **Spacing** — with ``[scatter] min_distance`` = s > 0, the survivors are
  thinned like the random method's candidates, by sequential dart throwing
  (:func:`~forest.scatter.poisson.poisson_thin`), but in order of final
  strength r·vigour: a plant is kept iff no stronger kept plant stands within
  s (stage ``min_distance``).  The dominant plant keeps its site, and the
  result is a maximal set with no two plants closer than s.
* Survivors' size in the species' ``scale`` range is r / R, so old dominant
  trees are large.

Deterministic: the only random draws are the shared per-candidate streams, and
ties break by candidate order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..config import Config
from ..errors import ConfigError, ForestError
from ..images import read_map_grey
from ..maps import sample_bilinear, terrain_moisture
from ..terrain import Terrain
from .candidates import Candidates, Progress
from .poisson import poisson_thin
from .survival import Survival

STAGES = ("site", "competition", "min_distance")
SITE, COMPETITION, SPACING = np.uint8(1), np.uint8(2), np.uint8(3)
MOISTURE_SOFTNESS = 0.1  # width of the Gaussian shoulder of the moisture preference
SHADE_TOLERANT = 0.5  # shade_tolerance at and above which undergrowth can survive beneath a canopy
UNDERGROWTH_RATIO = 0.5  # ... when its mature radius is under this share of the winner's


@dataclass(frozen=True)
class EcosystemParams:
    """The ecosystem's settings: ``[ecosystem]`` and per-species arrays (index = ``[[species]]`` order)."""

    years: int
    establish: float
    radius: np.ndarray  # mature radius R, m
    growth: np.ndarray  # growth rate g, 1/yr
    shade_tolerance: np.ndarray  # [0, 1]
    vigour: np.ndarray  # competitive strength multiplier
    moisture_lo: np.ndarray  # preferred moisture window
    moisture_hi: np.ndarray


def ecosystem_params(config: Config) -> EcosystemParams:
    """``[ecosystem] steps, establish`` and the species' ecosystem keys as arrays.

    The one place that reads them (``radius``, ``growth``, ``shade_tolerance``,
    ``vigour``, ``moisture``); the schema validated them when the file was read.
    """
    eco, sp = config.ecosystem, config.species
    return EcosystemParams(
        years=eco.steps,
        establish=eco.establish,
        radius=np.array([s.radius for s in sp], dtype=np.float64),
        growth=np.array([s.growth for s in sp], dtype=np.float64),
        shade_tolerance=np.array([s.shade_tolerance for s in sp], dtype=np.float64),
        vigour=np.array([s.vigour for s in sp], dtype=np.float64),
        moisture_lo=np.array([s.moisture[0] for s in sp], dtype=np.float64),
        moisture_hi=np.array([s.moisture[1] for s in sp], dtype=np.float64),
    )


def preference(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, soft: float) -> np.ndarray:
    """1 inside [lo, hi], exp(−½ (δ/soft)²) at a distance δ outside it."""
    d = np.maximum(lo - x, 0.0) + np.maximum(x - hi, 0.0)
    return np.exp(-0.5 * (d / max(soft, 1e-9)) ** 2)


def site_moisture(cand: Candidates, config: Config, terrain: Terrain) -> np.ndarray:
    """Moisture in [0, 1] at each candidate: the moisture map, else (1 − ĥ)(1 − θ/90°)."""
    if config.maps.moisture is not None:
        try:
            img = read_map_grey(config.maps.moisture, what="moisture map")
        except ForestError as e:
            raise ConfigError(config.path, "maps.moisture", str(e)) from None
        return np.clip(sample_bilinear(img, cand.u, cand.v), 0.0, 1.0)
    return terrain_moisture(cand.position[:, 1], cand.slope, terrain.height_range)


def grow_and_compete(
    position: np.ndarray,
    order: np.ndarray,
    potential: np.ndarray,
    mature: np.ndarray,
    growth: np.ndarray,
    vigour: np.ndarray,
    shade_tolerant: np.ndarray,
    years: int,
    progress: Progress,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate growth and competition of m plants over ``years``.

    ``potential`` is each plant's final radius R·f, ``mature`` the species' R,
    ``order`` the tie-break (smaller wins).  Returns which plants are alive
    (m,) bool and their radius at the end.
    """
    m = len(position)
    age = np.zeros(m)
    alive = np.ones(m, dtype=bool)
    for year in range(1, years + 1):
        progress(0.6 + 0.25 * year / years, f"year {year}/{years}")
        age[alive] += 1.0
        r = potential * (1.0 - np.exp(-growth * age))
        idx = np.flatnonzero(alive)
        if len(idx) < 2:
            break
        tree = cKDTree(position[idx], balanced_tree=False, compact_nodes=False)
        pairs = tree.query_pairs(2.0 * r[idx].max(), output_type="ndarray")
        if len(pairs) == 0:
            continue
        a, b = idx[pairs[:, 0]], idx[pairs[:, 1]]
        d = np.linalg.norm(position[a] - position[b], axis=1)
        over = r[a] + r[b] > d
        a, b = a[over], b[over]
        if len(a) == 0:
            continue
        sa, sb = r[a] * vigour[a], r[b] * vigour[b]
        a_wins = (sa > sb) | ((sa == sb) & (order[a] < order[b]))
        win = np.where(a_wins, a, b)
        lose = np.where(a_wins, b, a)
        beneath = shade_tolerant[lose] & (mature[lose] < UNDERGROWTH_RATIO * mature[win])
        alive[lose[~beneath]] = False
        # Undergrowth in shade grows more slowly this year.
        age[lose[beneath]] -= 0.5
    r = potential * (1.0 - np.exp(-growth * np.maximum(age, 0.0)))
    return alive, r


def spaced(position: np.ndarray, strength: np.ndarray, order: np.ndarray, min_distance: float) -> np.ndarray:
    """Mask of the plants kept by dart throwing at spacing ``min_distance``, strongest first (ties: ``order``)."""
    if min_distance <= 0 or len(position) < 2:
        return np.ones(len(position), dtype=bool)
    priority = np.lexsort((order, -strength))
    keep = np.empty(len(position), dtype=bool)
    keep[priority] = poisson_thin(position[priority], min_distance)
    return keep


def ecosystem_rule(cand: Candidates, config: Config, terrain: Terrain, progress: Progress) -> Survival:
    """Establishment by site fitness, then growth, competition and spacing (see the module docstring)."""
    par = ecosystem_params(config)
    k = cand.species
    fate = np.zeros(len(cand), dtype=np.uint8)
    progress(0.55, "site fitness")
    fit = preference(site_moisture(cand, config, terrain), par.moisture_lo[k], par.moisture_hi[k], MOISTURE_SOFTNESS)
    est = np.flatnonzero(fit >= par.establish)
    fate[fit < par.establish] = SITE
    ke = k[est]
    shade = par.shade_tolerance[ke] >= SHADE_TOLERANT
    alive, r = grow_and_compete(
        cand.position[est],
        cand.index[est],
        potential=par.radius[ke] * fit[est],
        mature=par.radius[ke],
        growth=par.growth[ke],
        vigour=par.vigour[ke],
        shade_tolerant=shade,
        years=par.years,
        progress=progress,
    )
    fate[est[~alive]] = COMPETITION
    live = np.flatnonzero(alive)
    progress(0.85, "min_distance")
    kept = spaced(
        cand.position[est[live]], r[live] * par.vigour[ke[live]], cand.index[est[live]], config.scatter.min_distance
    )
    fate[est[live[~kept]]] = SPACING
    alive[live[~kept]] = False
    return Survival(
        STAGES,
        fate,
        size=np.clip(r[alive] / par.radius[ke[alive]], 0.0, 1.0),
        columns={"radius": r[alive], "shade_tolerant": shade[alive]},
        meta={"method": "ecosystem", "years": par.years},
    )
