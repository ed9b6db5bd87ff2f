"""The cost of the sea past the terrain's edge: a wooded coast looking out to sea against the same terrain dry.

    .venv/bin/python bench/bench_sea.py [--size 640x360] [--spp 16] [--runs 2] [--keep DIR]

The terrain is a 1.2 km coast written here (:func:`coast_heights`: land rising inland from a wavy shoreline,
its far half under the sea), filled to 8 m (``[terrain] water``), 20 000 trees requested, far hills on the
skirt, the camera on the coast's hill looking along it and out to sea — the water runs on past the terrain's
edge to the horizon (forest.skirt, "The sea").  The baseline drops the ``water`` line: the same ground dry, the
skirt's far land and hills all round.  Whole ``forest render`` commands (scatter, scene build, render, EXR),
alternating, best of ``--runs`` by CPU seconds; printed with the tree counts and the shares of the frame's
pixels on the water and on the sea past the edge (the EXR's ``P`` against the water's plane and the extent).
``--keep DIR`` keeps both frames' EXR and PNG.
"""

from __future__ import annotations

import re
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from timing import alternate_renders, keep_renders, load_line, render_arguments, tree_count

LEVEL = 8.0
HALF = 600.0  # the terrain's half width, metres

CONFIG = f"""
name = "coast"
seed = 3
[terrain]
heightmap = "coast.png"
size = [{2 * HALF}, {2 * HALF}]
height = 120.0
water = {{ level = {LEVEL}, shore = 1.0 }}
[scatter]
count = 20000
[[species]]
model = "conifer"
percent = 60
[[species]]
model = "broadleaf"
percent = 40
[ground]
base = "grass"
[camera]
position = [-300.0, 90.0, -100.0]
target = [900.0, 25.0, 300.0]
fov = 55.0
far = 20000.0
[lights]
sun = {{ elevation = 25.0, azimuth = 120.0 }}
sky = {{ sunsky = {{ turbidity = 3.0 }} }}
clouds = {{ cover = 0.3 }}
[render]
visibility = 20.0
horizon_hills = {{ height = 200.0, scale = 2500.0 }}
denoise = true
look = "punchy"
exposure = 1.0
"""


def coast_heights(n: int = 257) -> np.ndarray:
    """(n, n) heights in [0, 1]: land rising from a wavy shoreline across the map's rows (the first rows highest)
    to a sea floor under the last ~40 % of them, with a faint ripple of relief."""
    x = np.linspace(0.0, 1.0, n)[None, :]
    z = np.linspace(0.0, 1.0, n)[:, None]
    shore = 0.55 + 0.08 * np.sin(9.0 * x)
    h = np.clip((shore - z) / 0.55, 0.0, None) ** 1.3 + 0.02 * np.sin(40.0 * x) * np.cos(31.0 * z)
    return np.clip(h, 0.0, 1.0)


def configs(folder: Path) -> dict[str, Path]:
    """The coast ("sea") and the same without its water line ("dry"), beside the heightmap."""
    import OpenImageIO as oiio

    h = coast_heights().astype(np.float32)
    buf = oiio.ImageBuf(oiio.ImageSpec(h.shape[1], h.shape[0], 1, oiio.UINT16))
    buf.set_pixels(oiio.ROI(), h[..., None])
    if not buf.write(str(folder / "coast.png")):
        raise SystemExit(f"bench_sea: cannot write the heightmap: {buf.geterror()}")
    dry = re.sub(r"^water = \{[^\n]*\n", "", CONFIG, count=1, flags=re.M)
    out = {}
    for name, body in (("sea", CONFIG), ("dry", dry)):
        out[name] = folder / f"{name}.toml"
        out[name].write_text(body)
    return out


def water_shares(exr: Path) -> tuple[float, float]:
    """(share of the frame's pixels whose first hit is within 5 cm of the water's level, share of them past the
    terrain's edge as well)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(exr))
    names = list(buf.spec().channelnames)
    if not {"P.X", "P.Y", "P.Z"} <= set(names):
        return float("nan"), float("nan")
    px = buf.get_pixels(oiio.FLOAT)
    x, y, z = (px[..., names.index(f"P.{c}")] for c in "XYZ")
    water = np.abs(y - LEVEL) < 0.05
    past = water & ((np.abs(x) > HALF) | (np.abs(z) > HALF))
    return float(water.mean()), float(past.mean())


def main() -> None:
    args = render_arguments(__doc__.splitlines()[0], "640x360")
    width, height = (int(v) for v in args.size.split("x"))
    print(f"sea: {load_line()} at start; the coast at {width}x{height} {args.spp} spp, whole forest render")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = configs(folder)
        best, summary = alternate_renders(paths, folder, ["render.aovs=['P']"], width, height, args.spp, args.runs)
        water, past = water_shares(folder / "sea.exr")
        for name, label in (("dry", "the coast dry (no water)"), ("sea", "the coast and its sea")):
            wall, cpu = best[name]
            print(f"sea {label:25s}: {wall:6.1f} s wall, {cpu:6.1f} CPU-s, {tree_count(summary[name])} trees")
        print(f"sea: {water:.1%} of the frame's pixels on the water, {past:.1%} on the sea past the terrain's edge")
        print(f"sea cost: {best['sea'][1] / best['dry'][1]:.2f}x CPU, {best['sea'][0] / best['dry'][0]:.2f}x wall")
        keep_renders(folder, list(paths), args.keep, "sea")
    print(f"sea: {load_line()} at end")


if __name__ == "__main__":
    main()
