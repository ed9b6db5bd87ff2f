"""Eroded mountains (``[render] horizon_hills`` ``erosion``, forest.erosion) and snow on them (``snowline``): their
cost, and the mountains' relief against a photograph's.

    .venv/bin/python bench/bench_erosion.py [--size 640x360] [--spp 16] [--runs 2]

The meadow (configs/meadow.toml: mountains past the forest, 1 200 m high, so fully eroded by default) rendered
by ``forest render`` with its erosion, without it (``erosion = 0``) and with a snow line at 800 m, alternating,
best of ``--runs`` each: wall and CPU seconds of the whole command, and the ratio to the smooth hills.  Then
the pictures: the
mountains' **relief contrast** — the standard deviation of the display luma's detail (the luma less its
Gaussian blur of σ = 1/160 of the width, blurred inside the mask only) over its mean, on the pixels that see
ground more than 1 km away (the EXR's depth) — set beside the same figure on the limestone ridge of the
shipped photograph ``autumn_larch_hillside`` (its painted mask's ground above the meadow), the meadow's pair
on the contact sheet.  The photograph is the truth here: nothing in the erosion was fitted to it.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from timing import forest_render, load_line, render_arguments

PHOTO = ROOT / "tests" / "fixtures" / "photos" / "autumn_larch_hillside.jpg"
#: Rows of the photograph above which its painted ground is the ridge, not the meadow.
RIDGE_ROWS = 110


def render(out: Path, sets: list[str], width: int, height: int, spp: int) -> tuple[float, float, str]:
    """One ``forest render`` of the meadow with ``--set`` ``sets``: (wall s, CPU s, its summary line)."""
    wall, cpu, done = forest_render(ROOT / "configs" / "meadow.toml", out, sets, width, height, spp)
    lines = [ln for ln in done.stdout.splitlines() + done.stderr.splitlines() if "triangles" in ln]
    return wall, cpu, (lines[-1].strip() if lines else "")


def luma(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of display-referred RGB in [0, 1]."""
    return rgb[..., :3] @ np.array([0.2126, 0.7152, 0.0722])


def relief_contrast(y: np.ndarray, mask: np.ndarray) -> float:
    """std of y's detail over mean y on ``mask``: detail = y − blur(y) with a Gaussian of σ = width / 160 taken
    inside the mask only (normalised convolution, so the sky and the trees beside the mountains do not leak in)."""
    from scipy.ndimage import gaussian_filter

    sigma = y.shape[1] / 160.0
    m = mask.astype(np.float64)
    blur = gaussian_filter(y * m, sigma) / np.maximum(gaussian_filter(m, sigma), 1e-9)
    inner = mask & (gaussian_filter(m, sigma) > 0.9)  # away from the mask's edge
    return float(np.std((y - blur)[inner]) / np.mean(y[inner]))


def skyline_roughness(solid: np.ndarray, mountain: np.ndarray) -> tuple[float, int]:
    """The skyline's roughness: per column, the top row of ``solid`` (anything but sky); over the columns where
    that pixel is ``mountain``, the standard deviation of the row less its Gaussian blur along the columns
    (σ = width / 80, blurred over those columns only), in units of the image's height.  (roughness, columns)."""
    from scipy.ndimage import gaussian_filter1d

    h, w = solid.shape
    top = np.where(solid.any(axis=0), solid.argmax(axis=0), h)
    cols = np.flatnonzero((top < h) & mountain[np.minimum(top, h - 1), np.arange(w)])
    if len(cols) < 8:
        return float("nan"), len(cols)
    sigma = w / 80.0
    m = np.zeros(w)
    m[cols] = 1.0
    row = top.astype(np.float64) * m
    blur = gaussian_filter1d(row, sigma) / np.maximum(gaussian_filter1d(m, sigma), 1e-9)
    inner = cols[gaussian_filter1d(m, sigma)[cols] > 0.9]
    return float(np.std((row - blur)[inner]) / h), len(inner)


def picture(png: Path, exr: Path) -> tuple[float, float, float]:
    """(relief contrast, skyline roughness, share of the frame) of the far ground in a render."""
    from forest.images import read_exr_channels, read_image

    rgb = read_image(png)[..., :3].astype(np.float64)
    depth = read_exr_channels(exr)[0]["depth.Z"]
    far = (depth > 1000.0) & (depth < 50_000.0)
    return relief_contrast(luma(rgb), far), skyline_roughness(depth < 50_000.0, far)[0], float(far.mean())


def photo() -> tuple[float, float, float]:
    """(relief contrast, skyline roughness, share of the frame) of the photograph's ridge."""
    from forest.images import read_image

    rgb = read_image(PHOTO)[..., :3].astype(np.float64)
    labels = read_image(PHOTO.with_name(PHOTO.stem + "_mask.png"))[..., :3]
    ground = (labels[..., 0] > 0.5) & (labels[..., 1] < 0.5) & (labels[..., 2] < 0.5)
    sky = (labels[..., 2] > 0.5) & (labels[..., 0] < 0.5)
    canopy = (labels[..., 1] > 0.5) & (labels[..., 0] < 0.5)
    upper = np.arange(ground.shape[0])[:, None] < RIDGE_ROWS
    ridge = ground & upper
    # The skyline: the ridge's top pixel may be one the painting left unlabelled (unsure), so any non-sky,
    # non-canopy pixel above the meadow counts there.
    top = upper & ~sky & ~canopy
    return relief_contrast(luma(rgb), ridge), skyline_roughness(~sky, top)[0], float(ridge.mean())


def main() -> None:
    args = render_arguments(__doc__.splitlines()[0], "640x360")
    w, h = (int(v) for v in args.size.split("x"))
    print(f"erosion: {load_line()} at start; meadow {w}x{h} {args.spp} spp")
    cases = {
        "smooth (erosion 0)": ["render.horizon_hills.erosion=0"],
        "eroded (erosion 1)": ["render.horizon_hills.erosion=1"],
        "eroded + snow 800 m": ["render.horizon_hills.erosion=1", "render.horizon_hills.snowline=800"],
    }
    best: dict[str, tuple[float, float]] = {}
    summary: dict[str, str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.keep or Path(tmp)
        out_dir.mkdir(parents=True, exist_ok=True)
        for _ in range(args.runs):
            for k, (name, sets) in enumerate(cases.items()):
                wall, cpu, line = render(out_dir / f"meadow_case{k}.exr", sets, w, h, args.spp)
                b = best.get(name)
                best[name] = (min(wall, b[0]), min(cpu, b[1])) if b else (wall, cpu)
                summary[name] = line
        base = best["smooth (erosion 0)"]
        for k, name in enumerate(cases):
            wall, cpu = best[name]
            contrast, rough, share = picture(out_dir / f"meadow_case{k}.png", out_dir / f"meadow_case{k}.exr")
            print(f"erosion {name:19s}: {wall:6.1f} s wall, {cpu:6.1f} CPU-s ({wall / base[0]:.2f}x wall, "
                  f"{cpu / base[1]:.2f}x CPU of smooth); far ground {share:.1%} of the frame, relief contrast "
                  f"{contrast:.4f}, skyline roughness {rough:.5f}")  # fmt: skip
            print(f"erosion {name:19s}: {summary[name]}")
    contrast, rough, share = photo()
    print(f"erosion photograph {PHOTO.stem}: the ridge {share:.1%} of the frame, relief contrast {contrast:.4f}, "
          f"skyline roughness {rough:.5f}")  # fmt: skip
    print(f"erosion: {load_line()} at end")


if __name__ == "__main__":
    main()
