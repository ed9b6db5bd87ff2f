"""Scatter benchmark: 1 000 000 trees with presence, density, colour and partition maps
and a slope rule; the same with the edge taper and with 1 000 trees placed by hand (``[[tree]]``; each
one's cost against the plain scatter); the same with Poisson-disk spacing; and the original's method (one
surface query per tree in a Python loop) on a sample, for the speed-up ratio.

    .venv/bin/python bench/bench_scatter.py [--trees 1000000]

Targets (2-core machine): ≤ 1 s without spacing, ≤ 10 s with, ≥ 300× the per-tree loop.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from forest.config import load_config
from forest.maps import MapSet
from forest.scatter import scatter
from forest.terrain import load_terrain

MAPS = ROOT / "configs" / "maps"

SCENE = """
seed = 1
[terrain]
heightmap = "{maps}/height.png"
size = [4000.0, 4000.0]
height = 300.0
[maps]
presence = "{maps}/presence.png"
density = "{maps}/density.png"
colour = "{maps}/colour.png"
partition = "{maps}/partition.png"
[partitions]
"#ff0000" = "foreground"
"#00ff00" = "midground"
"#0000ff" = "background"
[scatter]
count = {count}
min_distance = {min_distance}
[[species]]
model = "broadleaf"
percent = 60
slope_max = 30.0
[[species]]
model = "conifer"
percent = 40
"""


ECOSYSTEM = """
seed = 3
[terrain]
procedural = {{ size = 2500.0, height = 150.0, octaves = 6, resolution = 512 }}
[scatter]
method = "ecosystem"
count = {count}
[ecosystem]
steps = 15
[[species]]
model = "conifer"
percent = 30
radius = 3.5
growth = 0.2
altitude = [60.0, 150.0]
moisture = [0.0, 0.6]
[[species]]
model = "broadleaf"
percent = 40
radius = 5.0
growth = 0.3
moisture = [0.3, 1.0]
slope_max = 30.0
[[species]]
model = "shrub"
percent = 20
radius = 1.2
growth = 0.5
shade_tolerance = 0.8
[[species]]
model = "fern"
percent = 10
radius = 0.6
growth = 0.8
shade_tolerance = 1.0
moisture = [0.5, 1.0]
"""


def make_config(folder: Path, count: int, min_distance: float = 0.0, extra: str = "", tail: str = ""):
    """The benchmark scene; ``extra`` adds lines to its ``[scatter]`` table, ``tail`` tables at its end."""
    p = folder / f"bench_{count}_{min_distance}{'_x' if extra else ''}{'_t' if tail else ''}.toml"
    text = SCENE.format(maps=MAPS, count=count, min_distance=min_distance)
    p.write_text(text.replace("[scatter]\n", "[scatter]\n" + extra + "\n" if extra else "[scatter]\n") + tail)
    return load_config(p)


def original_loop(config, terrain, maps, n: int, seed: int = 0) -> int:
    """The 2005 method: per tree, pick a random (u, v), query the surface and every map."""
    rng = np.random.default_rng(seed)
    xmin, zmin, xmax, zmax = terrain.extent
    pct = np.cumsum([s.percent for s in config.species])
    kept = 0
    for _ in range(n):
        u, v = rng.random(), rng.random()
        x, z = xmin + u * (xmax - xmin), zmin + v * (zmax - zmin)
        y = terrain.height_at(x, z)[0]
        e = 0.5
        hx = (terrain.height_at(x + e, z)[0] - terrain.height_at(x - e, z)[0]) / (2 * e)
        hz = (terrain.height_at(x, z + e)[0] - terrain.height_at(x, z - e)[0]) / (2 * e)
        slope = math.degrees(math.atan(math.hypot(hx, hz)))
        uu, vv = np.array([u]), np.array([v])
        if not maps.present(uu, vv)[0]:
            continue
        if rng.random() >= maps.density_at(uu, vv)[0]:
            continue
        k = int(np.searchsorted(pct, rng.random() * 100, side="right"))
        if k >= len(pct) or slope > config.species[k].slope_max:
            continue
        maps.tint_at(np.array([x]), np.array([z]), terrain.extent)
        maps.partition_at(uu, vv)
        _ = (x, y, z, rng.random() * 2 * math.pi)
        kept += 1
    return kept


def timed(fn, repeat=3):
    best = math.inf
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trees", type=int, default=1_000_000)
    ap.add_argument("--sample", type=int, default=3000)
    ap.add_argument("--plants", type=int, default=100_000, help="ecosystem plants (approximate)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        probe, _ = scatter(make_config(tmp, 200_000))
        keep = len(probe) / 200_000
        count = int(args.trees / keep)
        cfg = make_config(tmp, count)
        t_plain, (inst, rep) = timed(lambda: scatter(cfg))
        print(
            f"scatter, 4 maps + slope rule: {len(inst):,} trees ({count:,} candidates) in {t_plain:.3f} s "
            f"(target ≤ 1 s)"
        )
        # The edge taper's cost: the presence map's distance transforms and one lookup per tree.
        cfg_t = make_config(tmp, count, extra="edge_taper = { width = 30.0, scale = 0.5 }")
        t_taper, (inst_t, _) = timed(lambda: scatter(cfg_t))
        print(
            f"scatter with [scatter] edge_taper (width 30 m): {len(inst_t):,} trees in {t_taper:.3f} s, "
            f"{t_taper / t_plain:.2f}x the same scatter without it; mean scale {inst_t.scale.mean():.3f} against "
            f"{inst.scale.mean():.3f}"
        )
        # Trees placed by hand: 1 000 [[tree]] entries over the terrain, each clearing its crown's radius.
        rng = np.random.default_rng(7)
        spots = rng.uniform(-1900.0, 1900.0, (1000, 2))
        placed = "".join(
            f'[[tree]]\nspecies = "{("broadleaf", "conifer")[i % 2]}"\nposition = [{x:.1f}, {z:.1f}]\n'
            for i, (x, z) in enumerate(spots)
        )
        cfg_h = make_config(tmp, count, tail=placed)
        t_hand, (inst_h, rep_h) = timed(lambda: scatter(cfg_h))
        print(
            f"scatter with 1 000 [[tree]] placed by hand: {len(inst_h):,} rows in {t_hand:.3f} s, "
            f"{t_hand / t_plain:.2f}x the same scatter without them; {rep_h.rejected['placed tree']:,} scattered "
            "trees cleared under their crowns"
        )
        # Poisson-disk: spacing chosen so that ~the same number of trees survives thinning.
        area = rep.area_m2
        r = 0.58 * math.sqrt(area * keep / (args.trees * 1.6))
        cfg_p = make_config(tmp, int(count * 1.6), r)
        t_pd, (inst_p, rep_p) = timed(lambda: scatter(cfg_p), repeat=1)
        print(
            f"scatter + Poisson-disk (min_distance {r:.2f} m): {len(inst_p):,} trees "
            f"({rep_p.candidates:,} candidates) in {t_pd:.3f} s (target ≤ 10 s)"
        )
        terrain = load_terrain(cfg.terrain, cfg.path)
        maps = MapSet(cfg)
        t0 = time.perf_counter()
        original_loop(cfg, terrain, maps, args.sample)
        per_cand = (time.perf_counter() - t0) / args.sample
        t_loop = per_cand * count
        print(
            f"original per-tree loop: {per_cand * 1e6:.1f} µs per candidate, {t_loop:.0f} s extrapolated "
            f"to {count:,} candidates (sample of {args.sample:,})"
        )
        print(f"speed-up vs per-tree loop: {t_loop / t_plain:.0f}× (target ≥ 300×)")
        eco = tmp / "eco.toml"
        eco.write_text(ECOSYSTEM.format(count=args.plants * 4))
        t_eco, (inst_e, rep_e) = timed(lambda: scatter(load_config(eco)), repeat=1)
        print(
            f"ecosystem (competition, {rep_e.candidates:,} seeds, 15 years): {len(inst_e):,} plants in "
            f"{t_eco:.2f} s (target ≤ 30 s for 100 000)"
        )
        print(f"machine: {platform.machine()}, {__import__('os').cpu_count()} cores, {platform.python_version()}")


if __name__ == "__main__":
    main()
