"""Ecosystem scatter: plants placed by competition and self-thinning, not only by percentages.

In the spirit of Deussen et al. 1998 ("Realistic modeling and rendering of
plant ecosystems", §3): every plant is a circle — its zone of influence — that
grows; where two circles overlap the weaker plant (the smaller circle) dies.
Selected as ``[scatter] method = "ecosystem"``.

Model, all steps vectorised over plants:

* **Seeding** — ``count`` seeds are drawn uniformly by surface area, masked by
  the presence and density maps like the random method, with species by
  ``percent`` (read as relative seeding rates; the remainder is bare ground).
* **Site fitness** f ∈ [0, 1] per seed: the product of Gaussian-shouldered
  preferences for altitude, slope and moisture (each species'
  ``altitude``/``slope_min``/``slope_max`` windows and ``moisture = [lo, hi]``).
  Moisture comes from ``[maps] moisture`` or, without a map, from the terrain:
  low and flat ground is wet (normalised height and slope).  Seeds with
  f < ``[ecosystem] establish`` never establish.
* **Growth** — over ``steps`` years, radius r(t) = R·f·(1 − e^(−g t)) with the
  species' mature ``radius`` R (m) and ``growth`` rate g (1/yr).
* **Competition** — each year, pairs with r_i + r_j > d_ij (a KD-tree query)
  are resolved: the plant with the larger r·vigour wins and the other dies —
  unless the loser is **shade tolerant** (``shade_tolerance`` ≥ 0.5) and its
  own mature radius is under half the winner's: undergrowth survives beneath
  a canopy, with its growth slowed by (1 − overlap share).
* Survivors become an :class:`~forest.instances.InstanceSet`; scale is the
  species' ``scale`` range mapped by r / R, so old dominant trees are large.

Deterministic: every random draw comes from a seeded stream.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from .config import Config
from .errors import ConfigError, ForestError
from .images import read_map_grey
from .instances import InstanceSet, yaw_tilt_quaternion
from .maps import MapSet, sample_bilinear
from .terrain import Terrain, load_terrain

TAG = 0xEC05


def _species_params(config: Config) -> dict[str, np.ndarray]:
    """Per-species ecosystem parameters as arrays (radius, growth, shade, vigour, moisture window)."""
    sp = config.species
    return {
        "radius": np.array([s.radius for s in sp], dtype=np.float64),
        "growth": np.array([s.growth for s in sp], dtype=np.float64),
        "shade": np.array([s.shade_tolerance for s in sp], dtype=np.float64),
        "vigour": np.array([s.vigour for s in sp], dtype=np.float64),
        "m_lo": np.array([s.moisture[0] for s in sp], dtype=np.float64),
        "m_hi": np.array([s.moisture[1] for s in sp], dtype=np.float64),
    }


def _window(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, soft: np.ndarray) -> np.ndarray:
    """1 inside [lo, hi], Gaussian fall-off of width ``soft`` outside."""
    d = np.maximum(lo - x, 0.0) + np.maximum(x - hi, 0.0)
    return np.exp(-0.5 * (d / np.maximum(soft, 1e-9)) ** 2)


def ecosystem_scatter(config: Config, progress=None, terrain: Terrain | None = None):
    from .scatter import ScatterReport, _streams

    t0 = time.perf_counter()
    step = progress or (lambda f, m="": None)
    years = config.ecosystem.steps
    establish = config.ecosystem.establish
    terrain = terrain or load_terrain(config.terrain, config.path)
    maps = MapSet(config)
    species = config.species
    names = [s.model for s in species]
    par = _species_params(config)
    n = config.scatter.count
    rng = _streams(config.seed, n)
    u = rng["position"].random((3, n))
    pos, face, bary = terrain.sample_points(u[0], u[1], u[2])
    mu, mv = terrain.to_uv(pos[:, 0], pos[:, 2])
    rejected = {"presence": 0, "density": 0, "empty ground": 0, "site": 0, "competition": 0}
    keep = maps.present(mu, mv)
    rejected["presence"] = int(n - keep.sum())
    d_u = rng["density"].random(n)
    if maps.density is not None:
        k2 = keep & (d_u < maps.density_at(mu, mv))
        rejected["density"] = int(keep.sum() - k2.sum())
        keep = k2
    pct = np.cumsum([sp.percent for sp in species])
    sp_idx = np.searchsorted(pct, rng["species"].random(n) * 100.0, side="right")
    empty = sp_idx >= len(species)
    rejected["empty ground"] = int((keep & empty).sum())
    keep &= ~empty
    live = np.flatnonzero(keep)
    k = sp_idx[live]
    P = pos[live]
    normal = terrain.normals_at(face[live], bary[live])

    # Site fitness from altitude, slope and moisture preferences.
    step(0.2, "site fitness")
    slope = np.degrees(np.arccos(np.clip(normal[:, 1], -1, 1)))
    hmin, hmax = terrain.height_range
    y = P[:, 1]
    if config.maps.moisture is not None:
        try:
            mimg = read_map_grey(config.maps.moisture, what="moisture map")
        except ForestError as e:
            raise ConfigError(config.path, "maps.moisture", str(e)) from None
        moisture = np.clip(sample_bilinear(mimg, mu[live], mv[live]), 0, 1)
    else:
        hn = (y - hmin) / max(hmax - hmin, 1e-9)
        moisture = np.clip((1.0 - hn) * (1.0 - slope / 90.0), 0.0, 1.0)
    s_lo = np.array([s.slope_min for s in species])[k]
    s_hi = np.array([s.slope_max for s in species])[k]
    a_lo = np.array([s.altitude[0] if s.altitude else -np.inf for s in species])[k]
    a_hi = np.array([s.altitude[1] if s.altitude else np.inf for s in species])[k]
    fit = (
        _window(slope, s_lo, s_hi, np.full(len(k), 5.0))
        * _window(y, a_lo, a_hi, np.full(len(k), 0.05 * max(hmax - hmin, 1.0)))
        * _window(moisture, par["m_lo"][k], par["m_hi"][k], np.full(len(k), 0.1))
    )
    est = fit >= establish
    rejected["site"] = int((~est).sum())
    live, k, P, normal, fit = live[est], k[est], P[est], normal[est], fit[est]

    # Growth and competition.
    R = par["radius"][k] * fit
    g = par["growth"][k]
    shade = par["shade"][k] >= 0.5
    Rmature = par["radius"][k]
    vig = par["vigour"][k]
    age_eff = np.zeros(len(k))
    alive = np.ones(len(k), dtype=bool)
    # Deterministic tie-break: seed order (candidate index).
    for year in range(1, years + 1):
        step(0.25 + 0.65 * year / years, f"year {year}/{years}")
        age_eff[alive] += 1.0
        r = R * (1.0 - np.exp(-g * age_eff))
        idx = np.flatnonzero(alive)
        if len(idx) < 2:
            break
        tree = cKDTree(P[idx], balanced_tree=False, compact_nodes=False)
        pairs = tree.query_pairs(2.0 * r[idx].max(), output_type="ndarray")
        if len(pairs) == 0:
            continue
        a, b = idx[pairs[:, 0]], idx[pairs[:, 1]]
        d = np.linalg.norm(P[a] - P[b], axis=1)
        over = r[a] + r[b] > d
        a, b, d = a[over], b[over], d[over]
        if len(a) == 0:
            continue
        sa, sb = r[a] * vig[a], r[b] * vig[b]
        a_wins = (sa > sb) | ((sa == sb) & (live[a] < live[b]))
        win = np.where(a_wins, a, b)
        lose = np.where(a_wins, b, a)
        under = shade[lose] & (Rmature[lose] < 0.5 * Rmature[win])
        dead = lose[~under]
        alive[dead] = False
        # Undergrowth in shade grows more slowly this year.
        shaded = lose[under]
        age_eff[shaded] -= 0.5
    rejected["competition"] = int((~alive).sum())
    r = R * (1.0 - np.exp(-g * np.maximum(age_eff, 0.0)))
    live, k, P, normal, r = live[alive], k[alive], P[alive], normal[alive], r[alive]

    step(0.95, "attributes")
    from .scatter import snap_yaw

    yaw = snap_yaw(rng["yaw"].random(n)[live] * 2 * np.pi, np.array([s.yaw_step for s in species])[k])
    phase = rng["phase"].random(n)[live] * 2 * np.pi
    rel = np.clip(r / par["radius"][k], 0.0, 1.0)
    lo = np.array([s.scale[0] for s in species])[k]
    hi = np.array([s.scale[1] for s in species])[k]
    align = np.array([config.scatter.align_to_normal if s.align is None else s.align for s in species])[k]
    su, sv = terrain.to_uv(P[:, 0], P[:, 2])
    inst = InstanceSet(
        id=live.astype(np.uint64),
        position=P,
        rotation=yaw_tilt_quaternion(yaw, normal, align),
        yaw=yaw,
        scale=lo + (hi - lo) * rel,
        species=k,
        tint=maps.tint_at(su, sv),
        partition=maps.partition_at(su, sv),
        normal=normal,
        phase=phase,
        species_names=names,
        partition_names=maps.partition_names,
        extent=terrain.extent,
        seed=config.seed,
        meta={
            "source": config.path.name if config.path else "",
            "method": "ecosystem",
            "height_range": list(terrain.height_range),
            "years": years,
        },
    )
    counts = inst.counts()
    rep = ScatterReport(
        candidates=n,
        kept=len(inst),
        area_m2=terrain.area,
        rejected=rejected,
        species=counts["species"],
        partitions=counts["partitions"],
    )
    rep.columns["radius"] = r
    rep.columns["shade_tolerant"] = shade[alive]
    rep.seconds = time.perf_counter() - t0
    step(1.0, "done")
    return inst, rep
