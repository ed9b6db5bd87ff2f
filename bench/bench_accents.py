"""Colour accents (``[[species]] accents``, forest.tint): their cost, and how many crowns are not green, against
photographs.

    .venv/bin/python bench/bench_accents.py [--size 480x270] [--spp 16] [--runs 2] [--keep DIR]

The jungle (configs/jungle.toml: flushing red and bronze, pale lime and yellow-flowering broadleaves, palms
with browning fronds) rendered by ``forest render`` as configured and with every accent removed
(``--set species[i].accents=[]``), alternating, best of ``--runs`` each: wall and CPU seconds of the whole
command and their ratio.  Then the tints alone: :func:`forest.tint.tree_tints` over a million trees with and
without the jungle's accents.

The picture: the **warm share** of the canopy — the share of its pixels with a warm hue (HSV hue below 60° or
from 330°: yellow, orange, red, brown) that is saturated (> 0.3) and not in shadow (value > 0.15) — on the
renders' tree pixels (the EXR's ``species`` layer ≥ 0, read from the sRGB PNG) and on the canopy masks of the
shipped photographs (``tests/fixtures/photos``, ``#00ff00``): above all ``aerial_road_conifers``, the jungle's
pair on the contact sheet, a nadir view over spruces with a few yellow larches among them.  The photographs are
the truth: no accent was fitted to them.  Per crown (renders only): the share of trees, of ≥ 12 pixels, whose
mean colour is warm by the same rule.

Then autumn: the meadow (configs/meadow.toml) with :data:`AUTUMN`'s accents — its broadleaves yellow, orange and
red, its birches yellow, half its shrubs turning, its spruces green — set beside the shipped photograph of an
autumn larch wood (``autumn_larch_hillside``, the meadow's pair): the warm share of the trees' pixels and the hue
(median, 10–90 %) of the warm ones.  The colours were chosen by eye for a mixed broadleaf wood, not from the
photograph, whose wood is all larch.
"""

from __future__ import annotations

import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_foliage_stats import PHOTOS, crown_means, hsv, read
from timing import forest_render, load_line, render_arguments

CONFIG = ROOT / "configs" / "jungle.toml"
PAIR = "aerial_road_conifers"
MEADOW = ROOT / "configs" / "meadow.toml"
#: The meadow in autumn (``--set`` overrides): docs/images/autumn.jpg and the comparison with the photograph.
AUTUMN = [
    "species[0].accents=[{share=0.45,colour=[0.45,0.30,0.03],amount=[0.6,1.0]},"
    "{share=0.35,colour=[0.45,0.15,0.03],amount=[0.6,1.0]},{share=0.1,colour=[0.30,0.05,0.03],amount=[0.6,1.0]}]",
    "species[1].accents=[{share=0.85,colour=[0.50,0.38,0.04],amount=[0.6,1.0]}]",
    "species[3].accents=[{share=0.5,colour=[0.35,0.15,0.03],amount=[0.4,0.9]}]",
]


def warm(px: np.ndarray) -> np.ndarray:
    """Rows of (N, 3) 8-bit pixels that are warm, saturated and lit (the module docstring's rule)."""
    h, s, v = hsv(px)
    return ((h < 60.0) | (h >= 330.0)) & (s > 0.3) & (v > 0.15)


def canopy_of_render(exr: Path, species_below: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(tree pixels (N, 3) uint8 of the PNG beside ``exr``, their tree ids), by the EXR's species and id layers;
    ``species_below``: only species indices below it (the ``[[species]]``, not the ``[[ground_cover]]``)."""
    import OpenImageIO as oiio

    names = list(oiio.ImageInput.open(str(exr)).spec().channelnames)
    layers = read(exr)
    species, ids = layers[..., names.index("species.Z")], layers[..., names.index("id.Z")]
    png = read(exr.with_suffix(".png"))[..., :3]
    keep = (species >= 0) & (species < (np.inf if species_below is None else species_below))
    return png[keep], ids[keep]


def warm_hues(px: np.ndarray) -> str:
    """``warm share S, hue median M° (10–90 % A–B°)`` of (N, 3) 8-bit pixels."""
    h, _, _ = hsv(px)
    w = warm(px)
    if not w.any():
        return f"warm share {w.mean():.3f}"
    p10, p50, p90 = np.percentile(h[w], [10, 50, 90])
    return f"warm share {w.mean():.3f}, warm hue median {p50:.0f}° (10–90 % {p10:.0f}–{p90:.0f}°)"


def canopy_of_photo(jpg: Path) -> np.ndarray:
    """The canopy pixels (N, 3) uint8 of a photograph: its painted mask's ``#00ff00``, every hue."""
    img = read(jpg)[..., :3]
    mask = read(jpg.with_name(jpg.stem + "_mask.png"))[..., :3]
    return img[(mask[..., 0] == 0) & (mask[..., 1] == 255) & (mask[..., 2] == 0)]


def accented_species(text: str) -> list[int]:
    """Indices of the ``[[species]]`` tables of the config text that set ``accents``."""
    return [i for i, s in enumerate(tomllib.loads(text).get("species", [])) if s.get("accents")]


def tint_cost(n: int = 1_000_000) -> tuple[float, float]:
    """Seconds of :func:`forest.tint.tree_tints` over ``n`` jungle trees (best of 3): (without, with accents)."""
    from forest.config import load_config
    from forest.library import open_library
    from forest.scatter.models import model_settings
    from forest.scatter.pipeline import resolve_models
    from forest.tint import tint_params, tree_tints

    cfg = load_config(CONFIG)
    settings = model_settings(cfg)
    params = tint_params(settings, resolve_models(cfg, open_library()), cfg.seed)
    rng = np.random.default_rng(0)
    species = rng.integers(0, len(settings), n)
    ids, ones = np.arange(n), np.ones((n, 3), np.float32)
    out = []
    for accents in (None, params.accents):
        best = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            tree_tints(ones, species, ids, cfg.seed, params.base, params.hue, params.value, accents)
            best = min(best, time.perf_counter() - t0)
        out.append(best)
    return out[0], out[1]


def main() -> None:
    args = render_arguments(__doc__.splitlines()[0], "480x270")
    w, h = (int(v) for v in args.size.split("x"))
    print(f"accents: {load_line()} at start; jungle {w}x{h} {args.spp} spp")
    off = [f"species[{i}].accents=[]" for i in accented_species(CONFIG.read_text())]
    cases = {"without accents": off, "with accents (as configured)": []}
    best: dict[str, tuple[float, float]] = {}
    shares: dict[str, tuple[float, float, int]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.keep or Path(tmp)
        out_dir.mkdir(parents=True, exist_ok=True)
        for _ in range(args.runs):
            for k, (name, sets) in enumerate(cases.items()):
                wall, cpu, _ = forest_render(CONFIG, out_dir / f"jungle_case{k}.exr", sets, w, h, args.spp)
                b = best.get(name)
                best[name] = (min(wall, b[0]), min(cpu, b[1])) if b else (wall, cpu)
        for k, name in enumerate(cases):
            px, tree = canopy_of_render(out_dir / f"jungle_case{k}.exr")
            crowns = crown_means(px, tree)
            shares[name] = (float(warm(px).mean()), float(warm(crowns).mean()), len(crowns))
    base = best["without accents"]
    for name in cases:
        wall, cpu = best[name]
        px_share, crown_share, n = shares[name]
        print(
            f"  {name:30s} {wall:6.1f} s wall  {cpu:6.1f} CPU-s  ({wall / base[0]:.2f}x wall, {cpu / base[1]:.2f}x CPU)"
            f"   warm share: pixels {px_share:.4f}, crowns {crown_share:.4f} of {n}"
        )
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.keep or Path(tmp)
        exr = out_dir / "meadow_autumn.exr"
        wall, cpu, _ = forest_render(MEADOW, exr, AUTUMN, w, h, args.spp)
        px, _ = canopy_of_render(exr, species_below=len(tomllib.loads(MEADOW.read_text())["species"]))
        print(f"  meadow in autumn ({wall:.1f} s wall): its trees' {warm_hues(px)}")
    print(
        f"  photograph autumn_larch_hillside's canopy: {warm_hues(canopy_of_photo(PHOTOS / 'autumn_larch_hillside.jpg'))}"
    )
    plain, accented = tint_cost()
    print(
        f"  tints of 1 000 000 trees: {plain * 1e3:.0f} ms without accents, {accented * 1e3:.0f} ms with "
        f"({accented / plain:.2f}x)"
    )
    print("photographs' canopy, warm share of pixels (every hue in the mask):")
    for jpg in sorted(PHOTOS.glob("*.jpg")):
        if not jpg.with_name(jpg.stem + "_mask.png").exists():
            continue
        px = canopy_of_photo(jpg)
        if len(px) >= 500:
            mark = "   <- the jungle's pair" if jpg.stem == PAIR else ""
            print(f"  {jpg.stem:28s} {warm(px).mean():.4f} of {len(px):,} px{mark}")


if __name__ == "__main__":
    main()
