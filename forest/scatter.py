"""Scatter: candidates on the terrain → maps and rules → an :class:`InstanceSet`.

The model (one pass, fully vectorised):

1. ``count`` candidate sites are drawn **uniformly by surface area** over the
   whole terrain (:meth:`forest.terrain.Terrain.sample`), so the expected number
   of trees per square metre of real surface is ``count / area`` everywhere,
   whatever the terrain's parametrisation.  ``count`` is therefore the number
   of trees the terrain would carry with every map white and species adding to
   100 %.
2. Each candidate is kept or rejected, in this order, and the report counts
   the rejections of each stage:

   * **presence** — the presence map's pixel is below the threshold;
   * **density**  — rejected with probability 1 − density (grey level);
   * **empty ground** — its species draw fell in the part of 100 % that no
     species claims;
   * **partition** — its species is limited to other regions (``partitions``);
   * **slope** / **altitude** — outside its species' window;
   * **min_distance** — Poisson-disk thinning (:mod:`forest.poisson`) among
     the survivors, in candidate order.

3. Survivors get yaw, scale (uniform in the species' range), wind phase, the
   colour map's tint and the partition map's region.

Every random quantity comes from its own seeded stream indexed by candidate,
so a tree's id and attributes do not change when a map edit removes another
tree.  Same config + seed ⇒ the same InstanceSet, byte for byte.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .config import Config
from .errors import ForestError
from .instances import InstanceSet, yaw_tilt_quaternion
from .maps import MapSet
from .terrain import Terrain, load_terrain

STREAMS = ("position", "density", "species", "yaw", "scale", "phase")
TAG = 0x5CA77E2


@dataclass
class ScatterReport:
    candidates: int
    kept: int
    area_m2: float
    rejected: dict[str, int] = field(default_factory=dict)  # stage → count
    rejected_by_species: dict[str, dict[str, int]] = field(default_factory=dict)
    species: dict[str, int] = field(default_factory=dict)
    partitions: dict[str, int] = field(default_factory=dict)
    unlabelled_pixels: int = 0
    unlabelled_colours: list = field(default_factory=list)
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    columns: dict = field(default_factory=dict)  # method-specific per-tree arrays (e.g. canopy radius)

    def lines(self) -> list[str]:
        out = [
            f"{self.kept:,} trees from {self.candidates:,} candidates over {self.area_m2 / 1e6:.3f} km² "
            f"in {self.seconds:.2f} s"
        ]
        out.append("  species:    " + ", ".join(f"{k} {v:,}" for k, v in self.species.items()))
        out.append("  partitions: " + ", ".join(f"{k} {v:,}" for k, v in self.partitions.items()))
        rej = [f"{k} {v:,}" for k, v in self.rejected.items() if v]
        out.append("  rejected:   " + (", ".join(rej) if rej else "none"))
        for sp, d in self.rejected_by_species.items():
            r = [f"{k} {v:,}" for k, v in d.items() if v]
            if r:
                out.append(f"    {sp}: " + ", ".join(r))
        out.extend(f"  warning: {w}" for w in self.warnings)
        return out


def _streams(seed: int, n: int):
    ss = np.random.SeedSequence([seed, TAG])
    gens = [np.random.Generator(np.random.PCG64(s)) for s in ss.spawn(len(STREAMS))]
    return dict(zip(STREAMS, gens))


def scatter(config: Config, progress=None, terrain: Terrain | None = None) -> tuple[InstanceSet, ScatterReport]:
    """Scatter the trees a config describes.  Raises :class:`ForestError` on bad input."""
    t0 = time.perf_counter()
    step = progress or (lambda f, m="": None)
    if config.scatter.method == "ecosystem":
        from .ecosystem import ecosystem_scatter

        return ecosystem_scatter(config, progress=progress, terrain=terrain)
    step(0.0, "terrain")
    terrain = terrain or load_terrain(config.terrain, config.path)
    step(0.15, "maps")
    maps = MapSet(config)
    species = config.species
    names = [s.model for s in species]
    n = config.scatter.count
    rng = _streams(config.seed, n)

    step(0.3, "candidates")
    u = rng["position"].random((3, n))
    position, face, bary = terrain.sample_points(u[0], u[1], u[2])
    idx = np.arange(n, dtype=np.int64)
    rejected = {
        "presence": 0,
        "density": 0,
        "empty ground": 0,
        "partition": 0,
        "slope": 0,
        "altitude": 0,
        "min_distance": 0,
    }

    # 1. presence (binary) and density (probabilistic), in map space.
    mu, mv = terrain.to_uv(position[:, 0], position[:, 2])
    keep = maps.present(mu, mv)
    rejected["presence"] = int(n - keep.sum())
    d_u = rng["density"].random(n)
    if maps.density is not None:
        k2 = keep.copy()
        k2[keep] = d_u[keep] < maps.density_at(mu[keep], mv[keep])
        rejected["density"] = int(keep.sum() - k2.sum())
        keep = k2

    # 2. species by percentages; the unclaimed remainder is empty ground.
    step(0.5, "species")
    pct = np.cumsum([sp.percent for sp in species])
    sp_draw = rng["species"].random(n) * 100.0
    sp_idx = np.searchsorted(pct, sp_draw, side="right")
    empty = sp_idx >= len(species)
    rejected["empty ground"] = int((keep & empty).sum())
    keep &= ~empty
    sp_idx = np.minimum(sp_idx, len(species) - 1)

    # 2b. species restricted to some partitions.
    if any(sp.partitions is not None for sp in species) and maps.partition is not None:
        live = np.flatnonzero(keep)
        part_live = maps.partition_at(mu[live], mv[live])
        pn = maps.partition_names
        allowed = np.ones((len(species), len(pn)), dtype=bool)
        for i, sp in enumerate(species):
            if sp.partitions is not None:
                allowed[i] = [name in sp.partitions for name in pn]
        bad = ~allowed[sp_idx[live], part_live]
        rejected["partition"] = int(bad.sum())
        keep[live[bad]] = False

    # 3. per-species slope and altitude windows (normals only where still needed).
    live = np.flatnonzero(keep)
    normal_live = terrain.normals_at(face[live], bary[live])
    slope = np.degrees(np.arccos(np.clip(normal_live[:, 1], -1.0, 1.0)))
    k_live = sp_idx[live]
    smin = np.array([sp.slope_min for sp in species])[k_live]
    smax = np.array([sp.slope_max for sp in species])[k_live]
    bad_slope_l = (slope < smin - 1e-9) | (slope > smax + 1e-9)
    alt_lo = np.array([sp.altitude[0] if sp.altitude else -np.inf for sp in species])[k_live]
    alt_hi = np.array([sp.altitude[1] if sp.altitude else np.inf for sp in species])[k_live]
    y = position[live, 1]
    bad_alt_l = ~bad_slope_l & ((y < alt_lo) | (y > alt_hi))
    rejected["slope"] = int(bad_slope_l.sum())
    rejected["altitude"] = int(bad_alt_l.sum())
    by_species = {}
    for k, nm in enumerate(names):
        m = k_live == k
        by_species[f"{nm}" if names.count(nm) == 1 else f"{nm}[{k}]"] = {
            "slope": int((bad_slope_l & m).sum()),
            "altitude": int((bad_alt_l & m).sum()),
        }
    ok_l = ~(bad_slope_l | bad_alt_l)
    keep[live[~ok_l]] = False
    live, normal_live = live[ok_l], normal_live[ok_l]

    # 4. Poisson-disk spacing among the survivors, in candidate order.
    if config.scatter.min_distance > 0 and keep.any():
        step(0.6, "min_distance")
        from .poisson import poisson_thin

        ok = poisson_thin(position[live], config.scatter.min_distance)
        rejected["min_distance"] = int((~ok).sum())
        keep[live[~ok]] = False
        live, normal_live = live[ok], normal_live[ok]

    step(0.8, "attributes")
    sel = live
    yaw = rng["yaw"].random(n)[sel] * (2 * np.pi)
    scale_u = rng["scale"].random(n)[sel]
    phase = rng["phase"].random(n)[sel] * (2 * np.pi)
    k = sp_idx[sel]
    yaw = snap_yaw(yaw, np.array([sp.yaw_step for sp in species])[k])
    lo = np.array([sp.scale[0] for sp in species])[k]
    hi = np.array([sp.scale[1] for sp in species])[k]
    align = np.array([config.scatter.align_to_normal if sp.align is None else sp.align for sp in species])[k]
    normal = normal_live
    inst = InstanceSet(
        id=idx[sel].astype(np.uint64),
        position=position[sel],
        rotation=yaw_tilt_quaternion(yaw, normal, align),
        yaw=yaw,
        scale=lo + (hi - lo) * scale_u,
        species=k,
        tint=maps.tint_at(mu[sel], mv[sel]),
        partition=maps.partition_at(mu[sel], mv[sel]),
        normal=normal,
        phase=phase,
        species_names=names,
        partition_names=maps.partition_names,
        extent=terrain.extent,
        seed=config.seed,
        meta={
            "source": config.path.name if config.path else "",
            "method": "random",
            "height_range": list(terrain.height_range),
        },
    )
    counts = inst.counts()
    report = ScatterReport(
        candidates=n,
        kept=len(inst),
        area_m2=terrain.area,
        rejected=rejected,
        rejected_by_species=by_species,
        species=counts["species"],
        partitions=counts["partitions"],
    )
    if maps.partition is not None and maps.partition.unlabelled_pixels:
        pm = maps.partition
        report.unlabelled_pixels = pm.unlabelled_pixels
        report.unlabelled_colours = pm.unlabelled_colours
        cols = ", ".join("#{:02x}{:02x}{:02x}".format(*c) for c in pm.unlabelled_colours)
        report.warnings.append(
            f"{pm.unlabelled_pixels:,} partition-map pixels match no label colour "
            f"(e.g. {cols}); their trees go to partition 'unlabelled'"
        )
    report.seconds = time.perf_counter() - t0
    step(1.0, "done")
    return inst, report


def snap_yaw(yaw: np.ndarray, step_deg: np.ndarray) -> np.ndarray:
    """Round yaw to multiples of ``step_deg`` where it is > 0 (e.g. 90° for street-aligned blocks)."""
    step = np.radians(step_deg)
    snapped = np.round(yaw / np.where(step > 0, step, 1.0)) * step
    return np.where(step > 0, np.mod(snapped, 2 * np.pi), yaw)


def scene_instances(
    config: Config, instances_path: str | Path | None = None, progress=None, terrain: Terrain | None = None
) -> InstanceSet:
    """The scene's InstanceSet: loaded from ``instances_path`` if given, else scattered."""
    if instances_path is None:
        return scatter(config, progress=progress, terrain=terrain)[0]
    inst = InstanceSet.load(instances_path)
    expected = [s.model for s in config.species]
    if list(inst.species_names) != expected:
        raise ForestError(
            f"{instances_path}: its species {inst.species_names} do not match the config's "
            f"[[species]] models {expected}; scatter again"
        )
    return inst
