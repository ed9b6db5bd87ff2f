"""The cost of still water (``[terrain] water``) and of its reeds: the demo with its lake against the same terrain dry.

    .venv/bin/python bench/bench_lake.py [--size 640x360] [--spp 16] [--runs 2] [--keep DIR]

Three configs from ``configs/demo.toml`` (its basin, ``maps/demo_height.png``): "reeds", the demo as it is;
"lake", without its reeds (the ``[[ground_cover]]`` of ``model = "reeds"``); "dry", without them and without
the ``water = {...}`` line of its ``[terrain]``, so trees grow on the basin's floor and the ground there is
painted by the rules.  Whole ``forest render`` commands (scatter, scene build, render, EXR), alternating,
best of ``--runs`` by CPU seconds; the tree counts (plants with the reeds) and the share of the frame's
pixels on the lake (the EXR's ``P.Y`` against the water's plane) are printed with them: the lake's cost is
lake / dry, the reeds' reeds / lake.
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


def configs(folder: Path) -> dict[str, Path]:
    """The demo as it is ("reeds"), without its reeds ("lake") and without them and its water line ("dry"), beside
    a link to its maps."""
    text = (ROOT / "configs" / "demo.toml").read_text()
    lake = re.sub(r'^\[\[ground_cover\]\][^\n]*\nmodel = "reeds"\n(?:(?!\[)[^\n]+\n)*\n', "", text, count=1, flags=re.M)
    dry = re.sub(r"^water = \{[^\n]*\n", "", lake, count=1, flags=re.M)
    if lake == text or dry == lake:
        raise SystemExit("bench_lake: configs/demo.toml has no reeds or no [terrain] water line")
    (folder / "maps").symlink_to(ROOT / "configs" / "maps")
    out = {}
    for name, body in (("reeds", text), ("lake", lake), ("dry", dry)):
        out[name] = folder / f"{name}.toml"
        out[name].write_text(body)
    return out


def water_share(exr: Path) -> float:
    """The share of the frame's pixels whose first hit is within 5 cm of the demo's water level (16 m)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(exr))
    names = list(buf.spec().channelnames)
    if "P.Y" not in names:
        return float("nan")
    y = buf.get_pixels(oiio.FLOAT)[..., names.index("P.Y")]
    return float(np.mean(np.abs(y - 16.0) < 0.05))


def main() -> None:
    args = render_arguments(__doc__.splitlines()[0], "640x360")
    width, height = (int(v) for v in args.size.split("x"))
    print(f"lake: {load_line()} at start; the demo at {width}x{height} {args.spp} spp, whole forest render")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        paths = configs(folder)
        best, summary = alternate_renders(paths, folder, ["render.aovs=['P']"], width, height, args.spp, args.runs)
        share = water_share(folder / "lake.exr")
        labels = (
            ("dry", "the basin dry (no water)"),
            ("lake", "the basin a lake"),
            ("reeds", "the lake and its reeds"),
        )
        for name, label in labels:
            wall, cpu = best[name]
            print(f"lake {label:26s}: {wall:6.1f} s wall, {cpu:6.1f} CPU-s, {tree_count(summary[name])} trees")
        print(f"lake: {share:.1%} of the frame's pixels on the water")
        print(f"lake cost: {best['lake'][1] / best['dry'][1]:.2f}x CPU, {best['lake'][0] / best['dry'][0]:.2f}x wall")
        print(
            f"reeds cost: {best['reeds'][1] / best['lake'][1]:.2f}x CPU, {best['reeds'][0] / best['lake'][0]:.2f}x wall"
        )
        keep_renders(folder, list(paths), args.keep, "lake")
    print(f"lake: {load_line()} at end")


if __name__ == "__main__":
    main()
