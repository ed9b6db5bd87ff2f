#!/usr/bin/env python3
"""A contact sheet of forest's views: each row a view (standard, filmic, agx), each column an exposure.

    .venv/bin/python scripts/view_sheet.py out/frame.exr out/views.png [--ev 0 2]
    .venv/bin/python scripts/view_sheet.py --chart out/chart.png      # a synthetic hue × exposure chart

The chart is a sweep of fully saturated hues (columns) over −4 … +8 EV around
18 % grey (rows), scene-linear Rec.709: it shows how each view takes bright
colour to white.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from forest.imaging import VIEWS, to_display  # noqa: E402


def hue_chart(width: int = 480, height: int = 240) -> np.ndarray:
    """Scene-linear chart: hue along x (saturated Rec.709 colours), exposure −4 … +8 EV along y (bottom → top)."""
    import colour

    h = np.linspace(0.0, 1.0, width, endpoint=False)
    hsv = np.stack([h, np.ones_like(h), np.ones_like(h)], axis=-1)
    rgb = np.asarray(colour.HSV_to_RGB(hsv))
    rgb = rgb / (rgb @ np.array([0.2126, 0.7152, 0.0722]))[:, None]  # unit luminance
    ev = np.linspace(8.0, -4.0, height)
    return (0.18 * np.exp2(ev)[:, None, None] * rgb[None]).astype(np.float32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("exr", nargs="?", help="a scene-linear EXR")
    ap.add_argument("out", help="the PNG to write")
    ap.add_argument("--ev", type=float, nargs="+", default=[0.0, 2.0])
    ap.add_argument("--chart", action="store_true", help="use the synthetic hue chart instead of an EXR")
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if args.chart:
        img = hue_chart()
        args.out = args.exr or args.out
    else:
        from forest.images import read_image

        img = read_image(args.exr)[..., :3]
    h, w = img.shape[:2]
    rows, cols = len(VIEWS), len(args.ev)
    fig, axes = plt.subplots(rows, cols, figsize=(cols * w / 100 + 0.4, rows * (h / 100 + 0.3)), dpi=100, squeeze=False)
    for r, view in enumerate(("standard", "filmic", "agx")):
        for c, ev in enumerate(args.ev):
            ax = axes[r][c]
            ax.imshow(to_display(img, view, ev), interpolation="nearest")
            ax.set_title(f"{view}  {ev:+g} EV", fontsize=9)
            ax.axis("off")
    fig.tight_layout(pad=0.3)
    fig.savefig(args.out)
    print(args.out)


if __name__ == "__main__":
    main()
