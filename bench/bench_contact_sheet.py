"""The gallery beside photographs: each example's render next to a real photograph of the same kind of view.

    .venv/bin/python bench/bench_contact_sheet.py                 # docs/images/contact_sheet.jpg
    .venv/bin/python bench/bench_contact_sheet.py -o /tmp/sheet.png --height 240

Each row is one example scene's gallery image (``docs/images/<scene>.jpg``, what
``bench/bench_gallery.py --images docs/images`` wrote) and, on its right, the shipped
photograph (``tests/fixtures/photos``, licences and authors in its README) chosen as the
nearest kind of view: the same camera height and framing, a forest of the same make-up.
Both are scaled to the same height (OpenImageIO's filtered resize) and nothing else is
changed, so exposure, colour and detail can be compared by eye.  The pairs, and why, are
:data:`PAIRS`; ``docs/gallery.md`` holds the written review of the sheet.

For each pair the script also prints the mean and 1st–99th percentile range of Rec. 709
luma Y′ and the mean HSV saturation of the whole frame (8-bit sRGB values), a coarse check
of the exposure and colour a reviewer compares by eye.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

ROOT = Path(__file__).resolve().parents[1]
PHOTOS = ROOT / "tests" / "fixtures" / "photos"
IMAGES = ROOT / "docs" / "images"

#: (scene, photograph, why this photograph is the nearest kind of view).
PAIRS: tuple[tuple[str, str, str], ...] = (
    ("demo", "wooded_lake_shore_hills", "a lake below wooded shores and hills, sky on the top third"),
    ("valley", "golden_hour_summit", "layered ridges receding into haze under a low sun"),
    ("meadow", "autumn_larch_hillside", "a forest edge across a meadow from eye level"),
    ("jungle", "aerial_road_conifers", "a steep aerial view down on a canopy cut by a river or road"),
    ("ecosystem", "fog_over_hillside", "a wooded slope and its ridge line against a hazy sky"),
    ("flythrough", "wooded_lake_shore_hills", "a lake below wooded shores and hills under fair-weather clouds"),
)
PAD = 8


def read_rgb(path: Path) -> np.ndarray:
    """An 8-bit image's RGB as float in [0, 1] (H, W, 3)."""
    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise SystemExit(f"{path}: {buf.geterror()}")
    px = np.asarray(buf.get_pixels(oiio.FLOAT))
    return px[..., :3] if px.shape[2] >= 3 else np.repeat(px, 3, axis=2)


def to_height(img: np.ndarray, height: int) -> np.ndarray:
    """``img`` resized (filtered) to ``height`` rows, aspect kept."""
    h, w = img.shape[:2]
    width = max(1, round(w * height / h))
    src = oiio.ImageBuf(oiio.ImageSpec(w, h, 3, oiio.FLOAT))
    src.set_pixels(oiio.ROI(), np.ascontiguousarray(img, np.float32))
    dst = oiio.ImageBufAlgo.resize(src, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, 3))
    return np.asarray(dst.get_pixels(oiio.FLOAT))


def stats(img: np.ndarray) -> str:
    """Mean luma, its 1st–99th percentile range (0–255) and the mean HSV saturation."""
    y = (img @ np.array([0.2126, 0.7152, 0.0722])) * 255.0
    mx, mn = img.max(axis=2), img.min(axis=2)
    sat = np.where(mx > 0, (mx - mn) / np.maximum(mx, 1e-6), 0.0)
    lo, hi = np.percentile(y, [1, 99])
    return f"luma mean {y.mean():5.1f} range {hi - lo:5.1f}  sat {sat.mean():.3f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, default=IMAGES / "contact_sheet.jpg")
    ap.add_argument("--height", type=int, default=200, help="row height in pixels")
    args = ap.parse_args()
    rows = []
    for scene, photo, why in PAIRS:
        render = read_rgb(IMAGES / f"{scene}.jpg")
        picture = read_rgb(PHOTOS / f"{photo}.jpg")
        print(f"{scene:>10}: {stats(render)}   |  {photo}: {stats(picture)}   ({why})")
        a, b = to_height(render, args.height), to_height(picture, args.height)
        gap = np.ones((args.height, PAD, 3), np.float32)
        rows.append(np.concatenate([a, gap, b], axis=1))
    width = max(r.shape[1] for r in rows)
    sheet = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=1.0) for r in rows]
    gap = np.ones((PAD, width, 3), np.float32)
    out = np.concatenate([x for r in sheet for x in (r, gap)][:-1], axis=0)
    spec = oiio.ImageSpec(out.shape[1], out.shape[0], 3, oiio.UINT8)
    spec.attribute("compression", "jpeg:88")  # a JPEG keeps the repository small; ignored for a PNG
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(out, np.float32))
    args.output.parent.mkdir(parents=True, exist_ok=True)
    if not buf.write(str(args.output)):
        raise SystemExit(f"{args.output}: {buf.geterror()}")
    print(f"wrote {args.output} ({out.shape[1]}x{out.shape[0]})")


if __name__ == "__main__":
    main()
