"""Foliage-pixel statistics of renders and photographs: does the canopy vary as much as a real one?

    .venv/bin/python bench/bench_foliage_stats.py                       # render the demo before | after
    .venv/bin/python bench/bench_foliage_stats.py --images a.exr b.exr  # or read renders (EXR + PNG beside)
    .venv/bin/python bench/bench_foliage_stats.py --gallery DIR          # every *.exr + PNG in DIR (the gallery's
                                                                         # full frames: bench_gallery.py --keep DIR)

"Before" is the demo with canopy structure off and the old per-tree colour jitter
(hue ±4°, value ±8 %); "after" is the demo as configured (the defaults of
:mod:`forest.scatter.canopy` and the stronger jitter).  Each render is made with
``forest render`` (its default renderer) at 480×270, 16 spp.  Both Mitsuba renderers show each
tree's own colour, the InstanceSet's ``tint`` column (forest_path exactly, as the map looked up at
each hit times the tree's jitter; scalar_rgb with the jitter quantised to a few bins per species);
before November 2026 they ignored the column and a ±90° hue jitter measured the same as ±4°.  Foliage pixels are those
whose EXR ``species`` layer names a tree (≥ 0); the statistics are read from the sRGB
PNG (8 bit), as a photograph would be.  The shipped reference photographs
(``tests/fixtures/photos``, each with a painted region mask; canopy = ``#00ff00``)
are measured the same way, their canopy mask further restricted to green hues
(HSV hue 40°–180°, saturation > 0.12) so that snow, autumn larches and sky glints
do not count.

Statistics (HSV of the 8-bit sRGB values, Smith 1978, "Color gamut transform pairs",
SIGGRAPH; Rec. 709 luma Y′ = 0.2126 R′ + 0.7152 G′ + 0.0722 B′):

* hue spread: the 5th–95th percentile range of the hue's deviation from the
  circular mean (degrees; wrapped to ±180°), and the circular standard deviation
  √(−2 ln R̄) (Mardia & Jupp 2000, *Directional Statistics*, §2.3.4), R̄ the mean
  resultant length of the hue angles;
* luma range: the 1st–99th percentile range of Y′ (0–255);
* saturation: the mean HSV saturation;
* black: the share of pixels with max(R′, G′, B′) ≤ 2.

Renders are also summarised per crown (the mean colour of each tree's foliage pixels, by the
EXR ``id`` layer, trees of ≥ 12 pixels): the tree-to-tree variation the per-tree colour jitter
controls, without the within-crown shading and sampling noise that dominate single pixels.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PHOTOS = ROOT / "tests" / "fixtures" / "photos"
OLD_JITTER = "{hue=4.0,value=0.08}"


def hsv(rgb8: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """HSV of (N, 3) 8-bit sRGB rows: hue degrees [0, 360), saturation and value in [0, 1]."""
    rgb = rgb8.astype(np.float64) / 255.0
    mx, mn = rgb.max(1), rgb.min(1)
    c = mx - mn
    r, g, b = rgb.T
    safe = np.where(c > 0, c, 1.0)
    h = np.where(mx == r, ((g - b) / safe) % 6, np.where(mx == g, (b - r) / safe + 2, (r - g) / safe + 4))
    return np.where(c > 0, h * 60.0, 0.0), np.where(mx > 0, c / np.where(mx > 0, mx, 1.0), 0.0), mx


def stats(rgb8: np.ndarray) -> dict[str, float]:
    """The module docstring's statistics of (N, 3) 8-bit pixels."""
    h, s, _ = hsv(rgb8)
    a = np.radians(h)
    z = np.exp(1j * a).mean()
    dev = np.degrees(np.angle(np.exp(1j * a) / (z / abs(z) if abs(z) > 0 else 1)))
    luma = rgb8.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    p5, p95 = np.percentile(dev, [5, 95])
    l1, l99 = np.percentile(luma, [1, 99])
    return {
        "hue_5_95": float(p95 - p5),
        "hue_circ_std": float(np.degrees(np.sqrt(-2 * np.log(max(abs(z), 1e-12))))),
        "luma_1_99": float(l99 - l1),
        "sat_mean": float(s.mean()),
        "black": float((rgb8.max(1) <= 2).mean()),
        "pixels": float(len(rgb8)),
    }


def read(path: Path) -> np.ndarray:
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    return np.asarray(buf.get_pixels(oiio.FLOAT if path.suffix == ".exr" else oiio.UINT8))


def green(px: np.ndarray) -> np.ndarray:
    """The rows of (N, 3) 8-bit pixels with a foliage hue: HSV hue 40°–180°, saturation > 0.12."""
    h, s, _ = hsv(px)
    return (h >= 40) & (h <= 180) & (s > 0.12)


def render_foliage(exr: Path) -> tuple[np.ndarray, np.ndarray]:
    """Foliage pixels (N, 3) uint8 of a render and their tree ids: the PNG beside ``exr`` where its
    species layer is ≥ 0 (a tree), green pixels only (:func:`green`, as for the photographs)."""
    import OpenImageIO as oiio

    spec = oiio.ImageInput.open(str(exr)).spec()
    names = list(spec.channelnames)
    layers = read(exr)
    species, ids = layers[..., names.index("species.Z")], layers[..., names.index("id.Z")]
    png = read(exr.with_suffix(".png"))[..., :3]
    px, tree = png[species >= 0], ids[species >= 0]
    keep = green(px)
    return px[keep], tree[keep]


def crown_means(px: np.ndarray, tree: np.ndarray, least: int = 12) -> np.ndarray:
    """The mean 8-bit colour of each tree covering at least ``least`` foliage pixels (tree-to-tree variation)."""
    u, inv, n = np.unique(tree, return_inverse=True, return_counts=True)
    sums = np.zeros((len(u), 3))
    np.add.at(sums, inv, px.astype(np.float64))
    return np.round(sums[n >= least] / n[n >= least, None]).astype(np.uint8)


def photo_foliage(jpg: Path) -> np.ndarray:
    """Canopy pixels of a photograph: its mask's ``#00ff00`` region, green hues only."""
    img = read(jpg)[..., :3]
    mask = read(jpg.with_name(jpg.stem + "_mask.png"))[..., :3]
    px = img[(mask[..., 0] == 0) & (mask[..., 1] == 255) & (mask[..., 2] == 0)]
    return px[green(px)]


def render_demo(out: Path, name: str, old: bool, width: int, height: int, spp: int) -> Path:
    exr = out / f"{name}.exr"
    cmd = [sys.executable, "-m", "forest.cli", "render", str(ROOT / "configs" / "demo.toml"), "-o", str(exr)]
    cmd += ["--width", str(width), "--height", str(height), "--spp", str(spp), "-q"]
    if old:
        cmd += ["--set", "scatter.clumping={strength=0.0,clearings=0.0}", "--set", "scatter.emergents={fraction=0.0}"]
        for i in range(3):
            cmd += ["--set", f"species[{i}].dead=0.0", "--set", f"species[{i}].colour_jitter={OLD_JITTER}"]
    subprocess.run(cmd, check=True, cwd=ROOT)
    return exr


def line(name: str, st: dict[str, float]) -> str:
    return (
        f"{name:34s} hue 5–95 % {st['hue_5_95']:6.1f}°  circ σ {st['hue_circ_std']:5.1f}°  "
        f"luma 1–99 % {st['luma_1_99']:6.1f}  sat {st['sat_mean']:.3f}  black {st['black']:.4f}  "
        f"({int(st['pixels']):,} px)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--images", nargs=2, type=Path, metavar=("BEFORE_EXR", "AFTER_EXR"))
    ap.add_argument("--size", nargs=2, type=int, default=(480, 270))
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--gallery", type=Path, metavar="DIR", help="measure every EXR (+ PNG beside) in DIR instead")
    args = ap.parse_args()
    if args.gallery:
        for exr in sorted(args.gallery.glob("*.exr")):
            px, tree = render_foliage(exr)
            if len(px) < 500:
                print(f"{exr.stem:34s} {len(px)} foliage pixels: too few to measure")
                continue
            print(line(exr.stem, stats(px)))
            print(line(f"  {exr.stem}, crown means", stats(crown_means(px, tree))))
        photo_lines()
        return
    with tempfile.TemporaryDirectory() as tmp:
        if args.images:
            before, after = args.images
        else:
            before = render_demo(Path(tmp), "before", True, *args.size, args.spp)
            after = render_demo(Path(tmp), "after", False, *args.size, args.spp)
        fb, fa = render_foliage(before), render_foliage(after)
    b, a = stats(fb[0]), stats(fa[0])
    cb, ca = stats(crown_means(*fb)), stats(crown_means(*fa))
    print(line("demo, before (structure off, ±4°/±8 %)", b))
    print(line("demo, after (defaults)", a))
    print(line("  crown means, before", cb))
    print(line("  crown means, after", ca))
    keys = ("hue_5_95", "hue_circ_std", "luma_1_99")
    print("after / before, pixels: " + "  ".join(f"{k} {a[k] / b[k]:.2f}" for k in keys))
    print("after / before, crowns: " + "  ".join(f"{k} {ca[k] / cb[k]:.2f}" for k in keys))
    photo_lines()


def photo_lines() -> None:
    """Print the statistics of every shipped photograph with a painted mask, and their median."""
    photos = sorted(p for p in PHOTOS.glob("*.jpg") if p.with_name(p.stem + "_mask.png").exists())
    rows = []
    for p in photos:
        px = photo_foliage(p)
        if len(px) >= 500:
            rows.append(stats(px))
            print(line(f"photo {p.stem}", rows[-1]))
    if rows:
        med = {k: float(np.median([r[k] for r in rows])) for k in rows[0]}
        print(line(f"photos, median of {len(rows)}", med))


if __name__ == "__main__":
    main()
