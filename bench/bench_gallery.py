"""The README gallery: every example scene at full quality, timed against its ``--preview`` render.

    .venv/bin/python bench/bench_gallery.py                               # every configs/*.toml
    .venv/bin/python bench/bench_gallery.py --scenes city,meadow --images docs/images
    .venv/bin/python bench/bench_gallery.py --size jungle=960x540          # a smaller frame, labelled

For each scene it runs the CLI exactly as the README's gallery does, one command at a time
(each its own process, nothing else of this script running beside it):

* the baseline, ``forest render SCENE --preview --variant llvm_ad_rgb`` (at most 480 px wide,
  8 spp, no motion blur, denoised when Open Image Denoise is installed);
* the full-quality frame, ``forest render SCENE --variant llvm_ad_rgb`` at the config's own
  width, height and spp (sub-frames and motion blur included).

and prints per scene the wall time of each whole command (scatter, scene load, render, the
EXR and the view-transformed PNG), the peak resident memory of each process (``ru_maxrss``
of that child alone, from :func:`os.wait4`) and the ratio full / preview of both.

A full frame whose estimated time is over ``--budget`` seconds (default 480: eight minutes)
is rendered at the largest 16:9 size that fits the estimate instead, and its line says so.
The estimate scales the preview's render phase by the ratio of samples (pixels × spp), an
upper bound since the preview's phase includes the kernel compilation a larger frame pays
once too.

``--images DIR`` copies each full-quality PNG into ``DIR/<scene>.jpg``, downscaled with
OpenImageIO (Lanczos) to the widest of 1280, 1120, 960, 800, 640 px that stays under
``--max-kb`` (default 300 KB) as a JPEG of quality 92 to 82 (:func:`shrink_image`), so the
repository stays small; ``--keep DIR`` keeps the full-size EXR and PNG of every scene.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_forest_path import cpu_model, load_average

#: Fast scenes first, so a run cut short still has most of the gallery.
ORDER = ("city", "demo", "meadow", "valley", "ecosystem", "flythrough", "jungle")
WIDTHS = (1280, 1120, 960, 800, 640)
VARIANT = "llvm_ad_rgb"


@dataclass
class Run:
    """One CLI command: wall seconds, the child's peak RSS in bytes, and its summary line."""

    wall: float
    peak: int
    summary: str

    @property
    def render_s(self) -> float:
        m = re.search(r"render ([\d.]+) s", self.summary)
        return float(m.group(1)) if m else self.wall

    @property
    def trees(self) -> str:
        m = re.search(r"([\d,]+) trees", self.summary)
        return m.group(1) if m else "?"


def run(args: list[str]) -> Run:
    """``forest ARGS`` in its own process; its wall time and its own peak RSS (``os.wait4``)."""
    exe = Path(sys.executable).parent / "forest"
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out:
        p = subprocess.Popen([str(exe), *args], cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read()
    if p.returncode != 0:
        raise SystemExit(f"forest {' '.join(args)} failed ({p.returncode}): {text.strip()[-2000:]}")
    summary = next((line for line in text.splitlines() if line.startswith("rendered")), "")
    return Run(wall, usage.ru_maxrss * 1024, summary)


def fit_size(width: int, height: int, scale: float) -> tuple[int, int]:
    """``width``×``height`` scaled by ``scale`` (≤ 1) in area, even sides, the aspect kept."""
    f = min(1.0, scale) ** 0.5
    return max(2, int(width * f) // 2 * 2), max(2, int(height * f) // 2 * 2)


#: JPEG qualities tried at each width, best first.
QUALITIES = (92, 90, 88, 85, 82)


def shrink_image(src: Path, dst: Path, max_bytes: int) -> tuple[int, int, str]:
    """Write ``src`` to ``dst`` (a JPEG) at the widest of :data:`WIDTHS` and the best of :data:`QUALITIES` under
    ``max_bytes``: its width, bytes and kind.

    Downscaled with OpenImageIO (Lanczos).  A JPEG keeps every hue: the 256-colour palette PNGs this wrote
    before turned the valley's sunlit tan clearing grey-white (it read as snow; 8×8-block means off by
    0.90/255 against the JPEG's 0.44/255), and at the same size a JPEG is 1280 px wide where the palette
    was 960.
    """
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(src))
    spec = buf.spec()
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.stem}.tmp.jpg")
    for w in WIDTHS:
        if w > spec.width:
            continue
        h = round(spec.height * w / spec.width)
        small = oiio.ImageBufAlgo.resize(buf, "lanczos3", roi=oiio.ROI(0, w, 0, h, 0, 1, 0, 3))
        for q in QUALITIES:
            small.specmod().attribute("Compression", f"jpeg:{q}")
            if not small.write(str(tmp), "uint8"):
                raise SystemExit(f"cannot write {tmp}: {small.geterror()}")
            if tmp.stat().st_size <= max_bytes or (w == WIDTHS[-1] and q == QUALITIES[-1]):
                tmp.replace(dst)
                return w, dst.stat().st_size, f"JPEG quality {q}"
    tmp.unlink(missing_ok=True)
    raise SystemExit(f"{src}: narrower than {WIDTHS[-1]} px")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    names = [n for n in ORDER if (ROOT / "configs" / f"{n}.toml").exists()]
    names += sorted(p.stem for p in (ROOT / "configs").glob("*.toml") if p.stem not in names)
    ap.add_argument("--scenes", default=",".join(names))
    ap.add_argument("--size", action="append", default=[], help="SCENE=WxH: render this scene at this size")
    ap.add_argument("--budget", type=float, default=480.0, help="seconds a full frame may take (estimate)")
    ap.add_argument("--images", type=Path, help="copy each full-quality picture here, downscaled, as a JPEG")
    ap.add_argument("--max-kb", type=int, default=300)
    ap.add_argument("--keep", type=Path, help="keep each full-quality EXR and PNG here (default: a temporary folder)")
    args = ap.parse_args()
    sizes = {k: tuple(int(v) for v in s.split("x")) for k, s in (a.split("=") for a in args.size)}

    print(f"gallery: {cpu_model()}, {os.cpu_count()} cores; load average {load_average()} at start", flush=True)
    with tempfile.TemporaryDirectory() as scratch:
        tmp = str(args.keep or scratch)
        Path(tmp).mkdir(parents=True, exist_ok=True)
        for name in args.scenes.split(","):
            cfg = ROOT / "configs" / f"{name}.toml"
            r = tomllib.loads(cfg.read_text()).get("render", {})
            w, h, spp = r.get("width", 1280), r.get("height", 720), r.get("spp", 64)
            base = ["render", f"configs/{name}.toml", "--variant", VARIANT]
            pre = run([*base, "--preview", "-o", f"{tmp}/{name}_preview.exr"])
            pw = min(w, 480)
            ph = round(h * pw / w)
            estimate = pre.wall - pre.render_s + pre.render_s * (w * h * spp) / (pw * ph * min(spp, 8))
            note = ""
            if name in sizes:
                w, h = sizes[name]
                note = f" (reduced by --size from the config's {r.get('width', 1280)}x{r.get('height', 720)})"
            elif estimate > args.budget:
                w, h = fit_size(w, h, args.budget / estimate)
                note = (
                    f" (reduced: the config's {r.get('width', 1280)}x{r.get('height', 720)} "
                    f"was estimated at {estimate:.0f} s > {args.budget:.0f} s)"
                )
            size_args = ["--width", str(w), "--height", str(h)] if note else []
            full = run([*base, *size_args, "-o", f"{tmp}/{name}.exr"])
            line = (
                f"gallery {name}: {full.trees} trees; full {w}x{h} {spp} spp{note} {full.wall:.0f} s, "
                f"peak {full.peak / 1e9:.2f} GB | preview {pw}x{ph} 8 spp {pre.wall:.0f} s, peak {pre.peak / 1e9:.2f} GB"
                f" | full/preview: time {full.wall / pre.wall:.1f}x, memory {full.peak / max(pre.peak, 1):.2f}x"
                f" | load average {load_average()}"
            )
            if args.images:
                iw, n, kind = shrink_image(Path(tmp) / f"{name}.png", args.images / f"{name}.jpg", args.max_kb * 1024)
                line += f" | image {iw} px wide, {kind}, {n / 1024:.0f} KB"
            print(line, flush=True)
    print(f"gallery: load average {load_average()} at end", flush=True)


if __name__ == "__main__":
    main()
