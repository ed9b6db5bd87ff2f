"""Look-dev benchmark: the aligned round trip on a production reference, and statistics mode on real photographs.

    .venv/bin/python bench/bench_lookdev.py [--out DIR] [--only round_trip|photos] [--photo NAME]
                                            [--iterations 6] [--spp 8] [--case 0 2 …] [--no-baseline]

1. **Aligned round trips on production references with sharp painted maps.**  A forest
   of 1 500 broadleaf trees on a 200 m hill, seen from straight above or obliquely; the
   truth is a *sharp* random painted colour map (8×8 or 16×16 patches whose colours
   are drawn over a foliage gamut — green, olive, yellow, red, dark, blue-green — with
   ±15 % brightness) and lights far from the start (the sun 27 % dimmer and warmer, the
   sky 25 % brighter and bluer); the reference is its production render at 256 spp,
   128×128.  The start is the same scene with a uniform grey colour map and the start
   lights, and ``forest.lookdev.match`` fits it with its defaults (``--grid auto``,
   ``map_prior = "edges"``, ``anchor = auto`` — the ground, which the truth shares).
   What a user does next decides: the written ``scene.toml`` and the truth are each
   rendered by ``forest render`` (128×128, 256 spp, the same seeds: common random
   numbers, :mod:`forest.lookdev.validation`) at the reference's camera, from a new
   low camera looking across the forest at the sky, and under a new sun (22°, from
   230°); printed: the mean per-pixel CIEDE2000 of each, beside its noise floor (the
   truth against itself with another seed), the map's pattern correlation (per-cell
   log colour, each channel's mean removed) on the cells the reference sees, the
   written sun's and sky's colour × level over the truth's, the weak directions
   reported, and the wall time.  Targets: correlation ≥ 0.9, ΔE ≤ 1.0 at the
   reference camera and ≤ 2.0 from the new camera and under the new sun, lights
   within 5 %, ≤ 60 s a match.  A baseline in the same run fits the first case with
   the smooth map prior of earlier versions (``map_prior = "smooth"``).
2. **The automatic segmentation against painted masks** on every photo in
   tests/fixtures/photos (real photographs from Debian's wallpaper packages, their
   licences and authors in its README; top-down aerials, a forest interior, hillsides,
   sunsets, mist, snow), each with a scene whose camera roughly frames what it shows
   (``tests/fixtures/photos/photo_scenes.py``) and a mask painted by hand (``paint_masks.py``): the
   intersection over union of sky, canopy and ground.
3. **Statistics mode on the same photos**, with the automatic regions and with the
   painted mask: per-region mean-colour CIEDE2000 photo vs start and photo vs fitted
   (production renders of the start config and of the written scene.toml), the whole
   image, the ratio fitted/start, the spread of L* and the lit-over-shadowed contrast
   beside the photo's, every bound a parameter ended on with the observation that drove
   it there, the weak directions, and the wall time; a contact sheet of the reports'
   renders to look at.  Targets: each region ≤ 8, whole image ≤ 5, ≤ 60 s each on 2
   cores.

Timings on a shared machine are noisy: compare the ratios (fitted against the
start of the same run), and re-run before quoting seconds.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
PHOTOS = ROOT / "tests" / "fixtures" / "photos"
sys.path.insert(0, str(PHOTOS))
from photo_scenes import PHOTO_SCENES

VARIANT = "llvm_ad_rgb"

FOREST = """
seed = 3
[terrain.procedural]
size = 200.0
height = 6.0
resolution = 32
[maps]
colour = "grey.png"
[scatter]
count = 1500
[[species]]
model = "broadleaf"
percent = 100
scale = [0.5, 0.8]
colour_jitter = {{ hue = 0.0, value = 0.0 }}
[camera]
position = {position}
target = {target}
up = {up}
fov = {fov}
[lights.sun]
elevation = 50
azimuth = 140
irradiance = {sun}
colour = {sun_colour}
[lights.sky]
radiance = {sky}
colour = {sky_colour}
[render]
width = 128
height = 128
spp = 16
max_depth = 3
[lookdev]
report_width = 256
"""
START = {"sun": 3.0, "sun_colour": [1.0, 0.95, 0.85], "sky": 0.4, "sky_colour": [0.6, 0.75, 1.0]}
TRUTH = {"sun": 2.2, "sun_colour": [1.0, 0.88, 0.7], "sky": 0.5, "sky_colour": [0.45, 0.65, 1.15]}
CAMERAS = {
    "top-down": {"position": [0.0, 260.0, 0.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 0.0, 1.0], "fov": 44},
    "oblique": {"position": [0.0, 150.0, -190.0], "target": [0.0, 0.0, 10.0], "up": [0.0, 1.0, 0.0], "fov": 55},
}
#: Views the written scene and the truth are both rendered in (config overrides applied to each).
VIEWS = {
    "reference camera": {},
    "new low camera": {
        "camera.position": [-60.0, 14.0, -95.0],
        "camera.target": [10.0, 2.0, 10.0],
        "camera.up": [0.0, 1.0, 0.0],
        "camera.fov": 60.0,
    },
    "new sun": {"lights.sun.elevation": 22.0, "lights.sun.azimuth": 230.0},
}
#: (camera, map patches per side, seed) of each round trip.
CASES = (("top-down", 8, 1), ("top-down", 8, 2), ("top-down", 16, 3), ("oblique", 8, 4), ("oblique", 16, 5))
#: Foliage colours a painted map's patches are drawn from (linear albedos; as multipliers of the broadleaf's).
FOLIAGE = np.array(
    [
        [0.06, 0.12, 0.04],  # green
        [0.09, 0.10, 0.03],  # olive
        [0.18, 0.15, 0.03],  # yellow
        [0.17, 0.06, 0.025],  # red
        [0.03, 0.06, 0.02],  # dark
        [0.05, 0.11, 0.07],  # blue-green
        [0.12, 0.14, 0.05],  # light green
    ]
)
LEAF = np.array([0.06, 0.12, 0.04])


def sharp_map(n: int, seed: int) -> np.ndarray:
    """An n×n painted map of sharp patches over the foliage gamut (multipliers of the broadleaf's colour)."""
    rng = np.random.default_rng(seed)
    m = (FOLIAGE / LEAF)[rng.integers(0, len(FOLIAGE), (n, n))] * np.exp(rng.normal(0.0, 0.15, (n, n, 1)))
    return m.astype(np.float32)


def write(folder: Path, text: str, name: str = "scene.toml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name
    p.write_text(textwrap.dedent(text))
    return p


def scene_text(camera: str, lights: dict) -> str:
    cam = {k: (v if not isinstance(v, list) else str(v)) for k, v in CAMERAS[camera].items()}
    return FOREST.format(**cam, **{k: (str(v) if isinstance(v, list) else v) for k, v in lights.items()})


def cli_render(config: Path, overrides: dict, seed: int, *, instances: Path, folder: Path, size: int, spp: int):
    """``forest render`` of ``config`` with ``overrides`` (and ``render.seed``), at size×size and ``spp``: the
    linear image of its EXR."""
    import subprocess

    import tomli_w

    from forest.config import load_config
    from forest.images import read_image

    view = load_config(config).with_overrides({**overrides, "render.seed": seed})
    folder.mkdir(parents=True, exist_ok=True)
    path = config.parent / f".view_{config.stem}.toml"
    path.write_text(tomli_w.dumps(view.data))
    exr = folder / f"{config.stem}_{abs(hash(repr(sorted(overrides.items())))) % 10**8}_{seed}.exr"
    cmd = [str(Path(sys.executable).parent / "forest"), "render", str(path), "--instances", str(instances)]
    cmd += ["-o", str(exr), "--width", str(size), "--height", str(size), "--spp", str(spp), "--quiet"]
    cmd += ["--variant", VARIANT]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    return np.asarray(read_image(exr), np.float64)[..., :3]


def round_trip(out: Path, camera: str, n: int, seed: int, *, iterations: int, spp: int, **options) -> dict:
    """One aligned round trip (module docstring, 1)."""
    from forest.config import load_config
    from forest.images import read_map_rgb, write_image
    from forest.lookdev import match
    from forest.lookdev.regions import render_labels
    from forest.lookdev.renders import FitRenderer
    from forest.lookdev.report import Production
    from forest.lookdev.validation import compare, covered_cells, pattern_correlation
    from forest.scene import load_scene

    folder = out / f"{camera}_{n}x{n}_seed{seed}{'_' + '_'.join(map(str, options.values())) if options else ''}"
    folder.mkdir(parents=True, exist_ok=True)
    write_image(folder / "grey.png", np.full((4, 4, 3), 0.2, np.float32))
    truth_map = sharp_map(n, seed)
    write_image(folder / "truth_map.exr", truth_map, half=False)
    start_cfg = load_config(write(folder, scene_text(camera, START)))
    scene = load_scene(start_cfg)
    instances = folder / "trees.npz"
    scene.instances.save(instances)
    truth_text = scene_text(camera, TRUTH).replace('colour = "grey.png"', 'colour = "truth_map.exr"')
    truth_text = truth_text.replace("[maps]\n", '[maps]\ncolour_normalise = "none"\n')
    truth_path = write(folder, truth_text, "truth.toml")
    truth = load_scene(load_config(truth_path), scene.instances)
    t0 = time.perf_counter()
    ref = Production(truth, VARIANT).image(width=128, height=128, spp=256, seed=9)
    t_ref = time.perf_counter() - t0
    write_image(folder / "reference.exr", ref.astype(np.float32), half=False)
    t0 = time.perf_counter()
    r = match(
        scene, folder / "reference.exr", folder / "out", iterations=iterations, spp=spp, resolution=128, **options
    )
    seconds = time.perf_counter() - t0
    fitted_cfg = load_config(r.scene_path)
    fr = FitRenderer(truth, width=128, height=128, spp=1, variant=VARIANT, base_map=None)
    seen = covered_cells(fr.layers, render_labels(fr.layers), (n, n))
    corr = pattern_correlation(read_map_rgb(fitted_cfg.maps.colour), truth_map, seen)

    def render(config, overrides, s):
        return cli_render(config, overrides, s, instances=instances, folder=folder / "views", size=128, spp=256)

    views = compare(r.scene_path, truth_path, VIEWS, width=128, height=128, spp=256, render=render)
    truth_cfg = truth.config

    def light(c, name):
        lt = getattr(c.lights, name)
        return np.multiply(lt.colour, lt.irradiance if name == "sun" else lt.radiance)

    return {
        "name": folder.name,
        "corr": corr,
        "cells": int(seen.sum()),
        "grid": r.grid,
        "anchor": r.anchor,
        "views": views,
        "sun": light(fitted_cfg, "sun") / light(truth_cfg, "sun"),
        "sky": light(fitted_cfg, "sky") / light(truth_cfg, "sky") if fitted_cfg.lights.sky.kind == "constant" else None,
        "weak": r.weak,
        "seconds": seconds,
        "reference_seconds": t_ref,
        "report": r.report_path,
    }


def print_round_trip(rt: dict) -> None:
    print(
        f"   {rt['name']}: map {rt['grid']}x{rt['grid']} cells, anchor {rt['anchor']}; match {rt['seconds']:.1f} s"
        f" ({'ok' if rt['seconds'] <= 60 else 'over 60 s'}), reference {rt['reference_seconds']:.1f} s"
    )
    print(
        f"     map pattern correlation {rt['corr']:.3f} on the {rt['cells']} cells the reference sees "
        f"({'ok' if rt['corr'] >= 0.9 else 'under 0.9'})"
    )
    for v in rt["views"]:
        goal = 1.0 if v.name == "reference camera" else 2.0
        print(
            f"     written scene vs truth, {v.name:>16}: CIEDE2000 {v.delta_e:5.2f} per pixel (noise floor "
            f"{v.floor:.2f}) {'ok' if v.delta_e <= goal else f'over {goal:g}'}"
        )
    sky = "n/a (written as an environment map)" if rt["sky"] is None else np.round(rt["sky"], 3).tolist()
    ok = np.all(np.abs(rt["sun"] - 1) <= 0.05) and (rt["sky"] is None or np.all(np.abs(rt["sky"] - 1) <= 0.05))
    print(f"     sun fitted/truth {np.round(rt['sun'], 3).tolist()}, sky {sky} ({'ok' if ok else 'over 5 %'})")
    for w in rt["weak"]:
        print(f"     weak direction: {w}")
    print(f"     report: {rt['report']}")


def segmentation(name: str, width: int = 64) -> dict[str, float]:
    """Per-class IoU of the automatic segmentation of photo ``name`` (guided by its scene's render) against its
    painted mask, at the fit's size."""
    from forest.config import parse_config
    from forest.lookdev.match import optimiser_size
    from forest.lookdev.reference import load_reference, painted_labels
    from forest.lookdev.regions import label_iou, render_labels, segment_photo
    from forest.lookdev.renders import FitRenderer
    from forest.scene import load_scene

    cfg = parse_config(textwrap.dedent(PHOTO_SCENES[name]), path=PHOTOS / "scene.toml", base_dir=PHOTOS)
    w, h = optimiser_size(cfg, width)
    ref = load_reference(PHOTOS / name, w, h, fit="crop")
    fr = FitRenderer(load_scene(cfg), width=w, height=h, spp=16, variant=VARIANT, base_map=None)
    auto = segment_photo(ref.rgb, render_labels(fr.layers), render_rgb=fr.render(seed=5))
    truth = painted_labels(PHOTOS / (Path(name).stem + "_mask.png"), ref, w, h, "crop")
    return label_iou(auto, truth)


def photo(out: Path, name: str, iterations: int, spp: int, painted: bool = False) -> dict:
    from forest.config import load_config
    from forest.lookdev import match
    from forest.scene import load_scene

    folder = out / (Path(name).stem + ("_painted" if painted else ""))
    t0 = time.perf_counter()
    scene = load_scene(load_config(write(folder, PHOTO_SCENES[name])))
    t_scene = time.perf_counter() - t0
    t0 = time.perf_counter()
    r = match(
        scene,
        PHOTOS / name,
        folder / "out",
        mode="statistics",
        iterations=iterations,
        spp=spp,
        resolution=64,
        mask=PHOTOS / (Path(name).stem + "_mask.png") if painted else None,
    )
    return {
        "figures": r.figures,
        "seconds": time.perf_counter() - t0,
        "scene_seconds": t_scene,
        "table": r.table,
        "warnings": r.warnings,
        "weak": r.weak,
        "report": r.report_path,
        "folder": folder,
    }


def contact_sheet(path: Path, runs: list[tuple[str, dict]]) -> Path:
    """One row per fit: the photo, the production render of the start and of the written scene (from each
    report's top row, cropped), side by side, to look at."""
    from PIL import Image

    rows = []
    for _name, p in runs:
        report = Image.open(p["report"]).convert("RGB")
        w, h = report.size
        top = report.crop((0, int(0.04 * h), w, int(0.04 * h) + int(0.24 * h)))
        rows.append(top.resize((1200, int(1200 * top.size[1] / top.size[0]))))
    sheet = Image.new("RGB", (1200, sum(r.size[1] for r in rows)), "white")
    y = 0
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.size[1]
    sheet.save(path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=6)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--case", type=int, nargs="*", default=None, help="Only these round trips (indices of CASES).")
    ap.add_argument("--no-baseline", dest="baseline", action="store_false", help="Skip the smooth-prior baseline.")
    ap.add_argument("--only", choices=("round_trip", "photos"), default=None)
    ap.add_argument("--out", type=Path, default=None, help="Keep the outputs (reports) here.")
    ap.add_argument("--photo", choices=sorted(PHOTO_SCENES), default=None, help="Only this photo.")
    a = ap.parse_args()
    import warnings

    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory(prefix="forest-bench-lookdev-") as d:
        out = a.out or Path(d)
        print(f"look-dev benchmark ({os.cpu_count()} CPUs visible, {VARIANT})")
        if a.only in (None, "round_trip"):
            print(
                f"\n1. aligned round trips on production references with sharp painted maps ({a.iterations} "
                f"iterations x {a.spp} spp at 128x128; views rendered by forest render at 128x128, 256 spp)"
            )
            cases = CASES if a.case is None else [CASES[i] for i in a.case]
            for camera, n, seed in cases:
                print_round_trip(round_trip(out, camera, n, seed, iterations=a.iterations, spp=a.spp))
            if a.baseline:
                camera, n, seed = CASES[0]
                print("   baseline: the first case with the smooth map prior of earlier versions")
                print_round_trip(
                    round_trip(out, camera, n, seed, iterations=a.iterations, spp=a.spp, map_prior="smooth", grid=16)
                )
        if a.only in (None, "photos"):
            names = [a.photo] if a.photo else list(PHOTO_SCENES)
            print(
                f"\n2. the automatic segmentation against painted masks ({len(names)} photos, 64 px wide): IoU per region"
            )
            ious: dict[str, list[float]] = {}
            for name in names:
                iou = segmentation(name)
                for k, v in iou.items():
                    ious.setdefault(k, []).append(v)
                print(f"   {name:>30}: " + ", ".join(f"{k} {v:.2f}" for k, v in iou.items()))
            print("   mean: " + ", ".join(f"{k} {np.mean(v):.2f} over {len(v)} photos" for k, v in ious.items()))
            print(
                f"\n3. statistics mode ({a.iterations} iterations x {a.spp} spp, 64 px wide), automatic regions and "
                "painted: per-region mean-colour CIEDE2000 photo vs start -> photo vs fitted (ratio)"
            )
            runs = []
            for name in names:
                for painted in (False, True):
                    p = photo(out, name, a.iterations, a.spp, painted)
                    runs.append((name, p))
                    f = p["figures"]
                    regions = "painted regions" if painted else "automatic regions"
                    print(f"   {name}, {regions}: {p['seconds']:.1f} s wall (scene {p['scene_seconds']:.1f} s)")
                    for region, de in f["fitted_regions"].items():
                        de0 = f["start_regions"].get(region, float("nan"))
                        goal = 5.0 if region == "whole image" else 8.0
                        st = f["region_statistics"].get(region, {})
                        spread = ""
                        if st.get("photo") and st.get("fitted"):
                            spread = (
                                f"  L* 10-90 %: photo {st['photo']['L*'][0]:.0f}-{st['photo']['L*'][2]:.0f}, "
                                f"fitted {st['fitted']['L*'][0]:.0f}-{st['fitted']['L*'][2]:.0f}"
                            )
                        c = st.get("lit_over_shadowed")
                        if c and c.get("photo") and c.get("fitted"):
                            spread += f"; lit/shadowed photo {c['photo']:.2f}, fitted {c['fitted']:.2f}"
                        print(
                            f"     {region:>18}: {de0:6.2f} -> {de:6.2f} ({de / max(de0, 1e-9):.2f}) "
                            f"{'ok' if de <= goal else f'over {goal:g}'}{spread}"
                        )
                    flags = [row for row in p["table"] if row["flag"] and not row["held"]]
                    for row in flags:
                        print(f"     {row['label']}: {row['start_shown']} -> {row['fitted_shown']} [{row['flag']}]")
                    for w in p["warnings"]:
                        if "ended on a bound" in w:
                            print(f"     bound: {w}")
                    for w in p["weak"]:
                        print(f"     weak direction: {w}")
                    print(f"     report: {p['report']}")
            print(f"   contact sheet: {contact_sheet(out / 'contact_sheet.png', runs)}")
        from forest.runtime import cuda_available

        if not cuda_available():
            print("\nGPU: none on this machine (cuda_ad_rgb timings not measured)")


if __name__ == "__main__":
    main()
