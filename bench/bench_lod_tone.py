"""Do the levels of detail keep a tree's tone?  Each level's rendered coverage and radiance against the high level's.

    .venv/bin/python bench/bench_lod_tone.py [--species broadleaf,conifer,birch,pine] [--spp 32] [--count 100000]
    .venv/bin/python bench/bench_lod_tone.py --fit broadleaf,conifer [--view aerial --keys far_top]
    .venv/bin/python bench/bench_lod_tone.py --check broadleaf,conifer
    .venv/bin/python bench/bench_lod_tone.py --examples demo,valley,flythrough,meadow,ecosystem,jungle

**Trees** (``--species``): 60 candidate sites on a flat 400 m square of dark ground (albedo 0.1), at least 25 m
apart, half of each of two species at a time, seen from 120 m up and 330 m back (480x270, ``max_depth`` 4, a sun
at 35° and a Hosek-Wilkie sky), rendered by ``forest render`` (forest_path, llvm_ad_rgb) once with every tree at
each level (``[lod] distances`` forcing it; solid cards off): per species, the pixels its trees cover (the EXR's
``species`` layer) and their summed RGB, each level over the high level's.  A level that keeps its tree's tone
scores 1.00 in both.

**Angles** (``--angles``, on by default): the far level against the high level, broadleaf and conifer, the same
trees seen from 350 m at 8°, 30°, 60° and 85° above the horizon: coverage and radiance per covered pixel.

**Forest** (``--count``): bench_cycles' scene (``--count`` trees requested over a terrain sized to keep the
density of the case study, 320x180), rendered with every tree at its highest level and with the automatic level
of detail (forest's default): the mean RGB of bands of rows from the horizon down, automatic over full.

**Fit** (``--fit A,B``, then nothing else): each lower level's tone in a forest, the factors a tree recipe's
``[lod_tone]`` carries.  bench_cycles' forest (100 000 trees requested, 60 % A and 40 % B, seen from 90 m,
960x540, 16 spp) is rendered with every tree high (the truth) and with the automatic levels; each level's pixels
are those that lose half their luminance when that level's leaves are rendered black.  The species' built
folders are copied into a private library whose ``species.json`` the fit rewrites (a level's leaf colour and
sheen weight, what ``[lod_tone]`` does at build).  Per species and level, a fixed point over ``--rounds``: with
the sheen off in both, the albedo factor g ← g · truth / automatic (per channel, summed over the level's
pixels); with it on, the sheen's own radiance (with minus without) in the automatic frame is matched to the
truth's by its weight.  ``--view aerial --keys far_top`` fits the far level's horizontal card from 700 m up.
It prints the recipe lines (the factors times the recipe's current ones).

**Check** (``--check A,B``): the recipes' tone against the same levels without it (the factors divided out),
at 640x360, on the fit view, under a low sun from the other side in a Hosek-Wilkie sky instead of a blue dome
(``sunsky``), from 700 m up (``aerial``) and from 250 m up (``oblique``, trees 15-30° below the camera): per
level, truth over automatic on its pixels, and the frame's bands and per-pixel difference.

**Examples** (``--examples``): each example config at 640x360, 16 spp (not denoised, no motion blur), with its
own light, haze, camera and ``[lod] distances``: the tree presets' levels toned and untoned against every tree
at its highest level; the frame, six bands of rows, and the mean difference of 8x8-pixel block means.

Both print their figures; nothing is asserted (the machine is shared).  The library's levels are built to match
the high level's *coverage* seen from the side (forest.library.build); their tone is set by the recipes'
``[lod_tone]``, fitted by ``--fit``.

Measured (AMD EPYC, 2 cores, idle): isolated trees, over high — broadleaf medium 1.12-1.20, low 1.24-1.44, far
0.76-0.96 (coverage 0.92); conifer 1.03-1.08, 1.16-1.24, 0.77-0.85; birch, pine alike; palm far 0.48-0.74
(coverage 0.59).  In the forest the pattern is not the same: the automatic level of detail over every tree high,
by bands from the horizon down, 1.10/0.97/1.17, 0.93/0.83/1.04, 0.92/0.87/0.99, 1.07/1.08/1.08, 1.06/1.11/1.06
(RGB) — the far band about right, the middle darker and less green, the near one brighter.  Tried and left: leaf
albedo factors per level fitted on the isolated trees (two secant rounds, to within about ±5 %) made the forest
worse (bands 1.43/1.35/1.32 … 0.81/0.79/0.89): in a closed canopy a level's brightness per covered pixel and its
shading by its neighbours count, not one tree's summed radiance, so a calibration has to be fitted in a forest
(and checked on another view and sun).  The far level's own error depends on the view's elevation: its three
vertical cards cover a broadleaf's crown 0.97 of the high level from 8° up, 0.87 from 30°, 0.57 from 60° and
0.32 from 85° (conifer 0.99, 0.88, 0.69, 0.41), and each covered pixel is less green (0.75-0.95): seen from
above a far tree is mostly the ground between its cards — a crossed-card impostor wants a horizontal card for
the top view.

With that card (forest.library.lod.impostor, November 28) the far level covers 1.000, 1.013, 1.029 and 1.038
of a broadleaf crown from 8°, 30°, 60° and 85° up (conifer 1.007, 0.969, 0.892, 0.952); each covered pixel is
still darker and less green (0.74-0.99).  ``--aerial`` (the forest seen from 700 m up, 20 000 trees
requested): with the cards alone the automatic rule had to keep trees seen more than 40° up at their low level
(16,712 trees: low 6,689, far 10,023, 10.1 M instanced triangles, load 1.2-1.4 s, render 3.1-3.6 s; over every
tree high the frame's mean 1.071, per-pixel relative mean difference 0.211); with the top card every tree is
far (0.22 M triangles, load 0.9-1.1 s, render 3.5-4.5 s: the far cards' cut-outs cost the traversal what the
triangles saved; frame mean 0.938, per-pixel 0.203).  From 90 m up (--count 100000) the bands moved
little (1.05/0.94/1.14 ... 1.04/1.10/1.04; per-pixel 0.381 before, 0.384 after).  Tried and left: the card
at the height where the crown is widest (a conifer's crown base, where from 30° up it no longer sticks out of
the spire as a skirt): coverage 1.014-1.064 (broadleaf), 0.900-1.000 (conifer), but the conifer's card lies in
the shade of its own vertical cards (radiance per pixel from 85° 0.85/0.77/0.89 against 0.99/0.90/1.04), and
per-pixel 0.207 (aerial) and 0.391 (from 90 m) against 0.203 and 0.384 — at the sizes the far level is drawn
(under 20 px) the numbers, not the close-up silhouette, decide.  The atlas without its baked sky visibility:
per pixel 1.12/1.15/1.21 from 8° (broadleaf; conifer 1.05/1.06/1.02) and 0.85-0.94 from 30-60°: the baked
shading darkens each far pixel by about a fifth from every angle, the crossed cards' own shadows a little more
from above; neither alone is the high level's tone.  Half of it (the splat's albedo times the square root of the
baked sky visibility, V = Y(shaded) / Y(albedo)) fits the isolated trees (green per pixel 0.92-1.14 at every
angle, from 0.72-0.90) and the aerial frame (per-pixel 0.193, frame 1.015), but not the forest seen from 90 m,
whose farthest rows of overlapping far crowns it makes a third too bright (bands 1.30/1.18/1.30, 1.12/1.03/1.20
... ; per-pixel 0.396 against 0.384): in a closed canopy the neighbours' shade is what the baked visibility
stands for.  Not kept.

Fitted in a forest (November 28, ``--fit``'s steps; the presets' medium, low and far factors by an earlier script
of the same steps with solid cards off, far_top by ``--fit --view aerial --keys far_top``): on each level's own
pixels, truth over automatic before the fit — broadleaf medium 0.89/0.88/0.93, low 0.77/0.75/0.79, far
0.96/1.08/0.79 (0.78x the truth's diffuse light without sheen, the flat cards' sheen reflecting the blue sky on
top: the "less green" of the far level); conifer 1.03/1.00/1.02, 0.92/0.90/0.90, 0.89/1.00/0.85; birch, pine and
palm alike (palm low 1.21/1.08/1.34: too dark) — after 3 rounds every level within 3.5 % per channel.  Held out
(``--check broadleaf,conifer``, 640x360): on the fit view the frame's bands 1.07-1.16 become 0.93-1.00 (per-pixel
0.546 -> 0.493; at 640 px each level is drawn 1.5x farther than at the fit's 960, and the residual is 4-7 %, the
other way); under a low sun from the other side and Hosek-Wilkie's sky the bands 1.05-1.38 become 0.93-1.12
(0.655 -> 0.587), broadleaf low 0.78 -> 1.02-1.03, conifer far 0.83/0.99/0.81 -> 0.98/1.02/1.02; from 250 m up
(crowns 15-30° below the camera) the top card 1.26 -> 0.93-0.97 and the frame 0.207 -> 0.198; from 700 m up the
frame 0.90/0.85/0.94 -> 0.95/0.92/0.95.  What a static tone cannot fix: the far level's vertical cards seen from
above stay 1.2-1.3x (from 250 m) and 1.4-1.8x (from 700 m) darker than the truth on their few pixels — their
tone depends on the elevation they are seen from.  On the examples (``--examples``, 8x8 blocks, untoned ->
toned): demo 0.0107 -> 0.0065, valley 0.0082 -> 0.0051, fly-through 0.0087 -> 0.0054, meadow 0.0180 -> 0.0158,
ecosystem 0.0096 -> 0.0092, jungle 0.313 -> 0.205 (seen straight down with every tree low: the low level's shape
from above, not its tone; at the gallery's 1280x720 the automatic rule, which the jungle now uses, gives its larger
crowns the medium level: 0.300 by distance, 0.210 automatic).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from bench_cycles import SCENE
from timing import load_line

FOREST = str(ROOT / ".venv" / "bin" / "forest")
LEVELS = {
    "high": "auto = false",
    "medium": "distances = [1.0, 100000.0, 200000.0]",
    "low": "distances = [1.0, 2.0, 200000.0]",
    "far": "distances = [1.0, 2.0, 3.0]",
}

TREES = """
seed = 4
[terrain]
flat = {{ size = 400.0 }}
[scatter]
count = 60
min_distance = 25.0
clumping = {{ strength = 0.0, clearings = 0.0 }}
emergents = {{ fraction = 0.0 }}
[[species]]
model = "{a}"
percent = 50
[[species]]
model = "{b}"
percent = 50
[camera]
position = [0.0, 120.0, -330.0]
target = [0.0, 0.0, 0.0]
fov = 50.0
[lights]
sun = {{ elevation = 35.0, azimuth = 140.0 }}
sky = {{ sunsky = {{ turbidity = 3.0 }} }}
[render]
width = 480
height = 270
spp = {spp}
max_depth = 4
horizon_ground = false
terrain_colour = [0.1, 0.1, 0.1]
[lod]
{lod}
solid_pixels = 0
"""


def render(
    cfg: Path,
    out: Path,
    lines: list[str] | None = None,
    env: dict[str, str] | None = None,
    args: tuple[str, ...] = (),
) -> dict[str, np.ndarray]:
    """``forest render`` of ``cfg`` (with the CLI options ``args``): its beauty RGB and its ``species`` layer;
    ``lines`` gets its summary line."""
    import OpenImageIO as oiio

    run = subprocess.run(
        [FOREST, "render", str(cfg), "-o", str(out), *args], check=True, capture_output=True, text=True, env=env
    )
    if lines is not None:
        lines.append(next((x for x in run.stdout.splitlines() if x.startswith("rendered")), ""))
    buf = oiio.ImageBuf(str(out))
    names = list(buf.spec().channelnames)
    px = buf.get_pixels(oiio.FLOAT)
    return {"rgb": px[..., :3], "species": px[..., names.index("species.Z")] if "species.Z" in names else None}


def horizon(full: np.ndarray, aerial: bool) -> int:
    """The first row below the horizon of a frame (0 when ``aerial``: no sky): rows of sky average over 0.1."""
    sky = np.flatnonzero(full.mean(axis=(1, 2)) > 0.1)
    return int(sky.max()) + 1 if len(sky) and not aerial else 0


def band_ratios(a: np.ndarray, f: np.ndarray, top: int, n: int) -> list[tuple[int, int, np.ndarray]]:
    """``n`` equal bands of rows from row ``top`` down: (first row, end row, mean RGB of ``a`` over ``f``'s)."""
    rows = f.shape[0] - top
    out = []
    for i in range(n):
        lo, hi = top + int(rows * i / n), top + int(rows * (i + 1) / n)
        out.append((lo, hi, a[lo:hi].mean(axis=(0, 1)) / np.maximum(f[lo:hi].mean(axis=(0, 1)), 1e-12)))
    return out


def trees(species: list[str], spp: int, tmp: Path) -> None:
    for a, b in zip(species[0::2], species[1::2] or species[:1]):
        images = {}
        for level, line in LEVELS.items():
            cfg = tmp / f"{a}_{b}_{level}.toml"
            cfg.write_text(TREES.format(a=a, b=b, spp=spp, lod=line))
            images[level] = render(cfg, tmp / f"{a}_{b}_{level}.exr")
        high = images["high"]
        for k, name in enumerate((a, b)):
            mh = high["species"] == k
            row = []
            for level in ("medium", "low", "far"):
                ml = images[level]["species"] == k
                cover = ml.sum() / max(mh.sum(), 1)
                rad = images[level]["rgb"][ml].sum(axis=0) / np.maximum(high["rgb"][mh].sum(axis=0), 1e-12)
                row.append(f"{level} coverage {cover:.3f}, radiance {rad[0]:.3f} {rad[1]:.3f} {rad[2]:.3f}")
            print(f"lod tone {name:10s} (over high): " + " | ".join(row))


def angles(spp: int, tmp: Path, elevations: tuple[float, ...] = (8.0, 30.0, 60.0, 85.0)) -> None:
    """The far level (three vertical crossed cards) over the high level, broadleaf and conifer, from 350 m at
    camera elevations from grazing to straight down: coverage and radiance per covered pixel."""
    import math

    for elev in elevations:
        y, z = 350.0 * math.sin(math.radians(elev)), -350.0 * math.cos(math.radians(elev))
        images = {}
        for level in ("high", "far"):
            text = TREES.format(a="broadleaf", b="conifer", spp=spp, lod=LEVELS[level])
            text = text.replace("position = [0.0, 120.0, -330.0]", f"position = [0.0, {y:.1f}, {z:.1f}]")
            if elev > 80.0:  # a look-at straight down needs the target a little off the camera's vertical
                text = text.replace("target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 1.0]")
            cfg = tmp / f"angle_{level}_{elev:g}.toml"
            cfg.write_text(text)
            images[level] = render(cfg, tmp / f"angle_{level}_{elev:g}.exr")
        row = []
        for k, name in enumerate(("broadleaf", "conifer")):
            mh, mf = images["high"]["species"] == k, images["far"]["species"] == k
            cover = mf.sum() / max(mh.sum(), 1)
            per = (
                images["far"]["rgb"][mf].sum(axis=0) / np.maximum(images["high"]["rgb"][mh].sum(axis=0), 1e-12) / cover
            )
            row.append(f"{name} coverage {cover:.3f}, radiance per pixel {per[0]:.3f} {per[1]:.3f} {per[2]:.3f}")
        print(f"lod tone far level seen from {elev:g}° up (over high): " + " | ".join(row))


def forest(count: int, spp: int, tmp: Path, aerial: bool = False) -> None:
    size = float(np.sqrt(count / 130_000.0) * 4000.0)
    text = SCENE.format(size=size, count=count, camz=-0.5 * size, width=320, height=180, spp=spp, depth=3, seed=1)
    if aerial:  # 700 m up over the terrain's near edge, looking down at a point 600 m in: trees seen 40-70° up
        text = text.replace("position = [0.0, 90.0,", "position = [0.0, 700.0,")
        text = text.replace("target = [0.0, 20.0, 0.0]", f"target = [0.0, 0.0, {-0.5 * size + 600.0:.1f}]")
    full, auto = tmp / "full.toml", tmp / "auto.toml"
    full.write_text(text.replace("[lod]\nauto = false\n", "[lod]\nauto = false\nsolid_pixels = 0\n"))
    auto.write_text(text.replace("[lod]\nauto = false\n", "[lod]\n"))
    lines: list[str] = []
    a, f = render(auto, tmp / "auto.exr", lines)["rgb"], render(full, tmp / "full.exr", lines)["rgb"]
    h = horizon(f, aerial)
    view = "from 700 m up" if aerial else "from 90 m up"
    parts = [f"rows {lo}-{hi} {r[0]:.3f} {r[1]:.3f} {r[2]:.3f}" for lo, hi, r in band_ratios(a, f, h, 5)]
    print(
        f"lod tone forest {count:,} trees {view}, automatic over every tree high (mean RGB by band): "
        + " | ".join(parts)
    )
    for name, line in zip(("automatic", "every tree high"), lines):
        print(f"lod tone forest {name}: {line}")
    below = slice(h, None)  # the forest's rows: per pixel, |automatic − full| over the full frame's mean (noise too)
    err = float(np.abs(a[below] - f[below]).mean() / max(float(f[below].mean()), 1e-12))
    print(
        f"lod tone forest whole frame: {a.mean() / f.mean():.4f}; per-pixel relative mean difference below the "
        f"horizon {err:.3f}"
    )


TONED = ("medium", "low", "far", "far_top")  # far_top: the far level's horizontal card (its own part)
LUMA = np.array([0.2126, 0.7152, 0.0722])


class ToneLibrary:
    """A private copy of the built species whose lower levels' leaf albedo and sheen weight a fit scales.

    Each level's parts are read from its species' ``species.json``; scaling the colour and sheen written there
    is what a recipe's ``[lod_tone]`` does at build (``forest.library.build.toned``), without rebuilding.
    ``factors[name][level] = (albedo RGB, sheen)`` multiply the levels *as built*, i.e. on top of the recipe's
    current tone; :meth:`untoned` gives the factors that undo the recipe's tone (the levels as they were before
    it), the baseline of ``--check``.
    """

    def __init__(self, tmp: Path, species: tuple[str, ...], individuals_each: int = 4):
        from forest.library import individuals, open_library
        from forest.library.generator import validate_recipe

        self.root, self.species = tmp / "library", species
        lib = open_library()
        self.tone = {name: validate_recipe(lib.recipe(name)[0])["lod_tone"] for name in species}
        self.meta: dict[Path, dict] = {}
        for name in species:
            for sp in individuals(lib, name, individuals_each):
                dst = self.root / "cache" / sp.folder.name
                shutil.copytree(sp.folder, dst)
                self.meta[dst / "species.json"] = json.loads((dst / "species.json").read_text())
        self.env = dict(os.environ, FOREST_LIBRARY=str(self.root))

    def untoned(self) -> dict[str, dict[str, tuple[np.ndarray, float]]]:
        return {
            name: {lv: (1.0 / np.array(t[lv]["albedo"]), 1.0 / max(t[lv]["sheen"], 1e-6)) for lv in TONED}
            for name, t in self.tone.items()
        }

    def set(self, factors: dict[str, dict[str, tuple[np.ndarray, float]]] | None = None, sheen: bool = True) -> None:
        """Write every copied species.json with ``factors`` (none: as built); ``sheen = False`` turns sheen off."""
        for path, meta in self.meta.items():
            m = json.loads(json.dumps(meta))
            f = (factors or {}).get(m["name"].split("@")[0], {})
            for level in m["lods"]:
                for part in level["parts"]:
                    if part["kind"] != "leaf":
                        continue
                    key = "far_top" if part["file"] == "far_top.ply" else level["name"]
                    albedo, sh = f.get(key, (np.ones(3), 1.0))
                    part["colour"] = [float(c) * float(a) for c, a in zip(part["colour"], albedo)]
                    if "sheen" in part:
                        part["sheen"] = min(1.0, float(part["sheen"]) * sh) if sheen else 0.0
            path.write_text(json.dumps(m, indent=1, sort_keys=True) + "\n")


def tone_scene(species: tuple[str, ...], width: int, height: int, spp: int, lod: str, view: str = "fit") -> str:
    """bench_cycles' forest (100 000 trees requested, 60/40 % of two species) from 90 m up, or a held-out view."""
    size = float(np.sqrt(100_000 / 130_000.0) * 4000.0)
    text = SCENE.format(
        size=size, count=100_000, camz=-0.5 * size, width=width, height=height, spp=spp, depth=3, seed=1
    )
    text = text.replace('model = "broadleaf"', f'model = "{species[0]}"').replace(
        'model = "conifer"', f'model = "{species[1]}"'
    )
    if view in ("aerial", "oblique"):  # 700 m up looking at a point 600 m in (crowns seen 40-70° up), or 250 m up
        y, z = (700.0, 600.0) if view == "aerial" else (250.0, 800.0)  # at one 800 m in (15-30° up)
        text = text.replace("position = [0.0, 90.0,", f"position = [0.0, {y},")
        text = text.replace("target = [0.0, 20.0, 0.0]", f"target = [0.0, 0.0, {-0.5 * size + z:.1f}]")
    elif view == "sunsky":  # a low sun from the other side under Hosek-Wilkie's sky instead of a blue dome
        text = text.replace("elevation = 35.0, azimuth = 140.0", "elevation = 15.0, azimuth = 250.0")
        text = text.replace(
            "sky = { radiance = 0.45, colour = [0.55, 0.7, 1.0] }", "sky = { sunsky = { turbidity = 3.0 } }"
        )
    return text.replace("[lod]\nauto = false\n", "[lod]\n" + (lod + "\n" if lod else ""))  # solid cards as by default


class ToneCase:
    """One view of the forest rendered through a :class:`ToneLibrary`: every tree high (the truth), the
    automatic levels, and each lower level's pixels (the automatic frame with that level's leaves black)."""

    def __init__(
        self, lib: ToneLibrary, tmp: Path, view: str, width: int, height: int, spp: int, keys: tuple[str, ...] = TONED
    ):
        self.lib, self.tmp, self.view, self.size = lib, tmp, view, (width, height, spp)
        lib.set()
        self.high = self.render("high", LEVELS["high"])
        auto = self.render("auto")
        self.masks: dict[tuple[str, str], np.ndarray] = {}
        for level in keys:
            lib.set({n: {level: (np.zeros(3), 1.0)} for n in lib.species})
            black = self.render(f"black_{level}")
            for k, name in enumerate(lib.species):
                m = (auto["species"] == k) & (black["rgb"] @ LUMA < 0.5 * (auto["rgb"] @ LUMA))
                if m.sum() >= 50:
                    self.masks[(name, level)] = m
        lib.set()

    def render(self, name: str, lod: str = "") -> dict[str, np.ndarray]:
        w, h, spp = self.size
        cfg = self.tmp / f"{self.view}_{name}.toml"
        cfg.write_text(tone_scene(self.lib.species, w, h, spp, lod, self.view))
        return render(cfg, self.tmp / f"{self.view}_{name}.exr", env=self.lib.env)

    def ratios(self, high: np.ndarray, auto: np.ndarray) -> dict[tuple[str, str], np.ndarray]:
        """Per species and level: the truth's summed RGB over the automatic frame's, on that level's pixels."""
        return {key: high[m].sum(axis=0) / np.maximum(auto[m].sum(axis=0), 1e-12) for key, m in self.masks.items()}

    def frame(self, auto: np.ndarray) -> str:
        """Bands of rows below the horizon (automatic over every tree high) and the per-pixel relative difference."""
        f = self.high["rgb"]
        h0 = horizon(f, self.view in ("aerial", "oblique"))
        parts = [f"{r[0]:.2f}/{r[1]:.2f}/{r[2]:.2f}" for _, _, r in band_ratios(auto, f, h0, 5)]
        err = float(np.abs(auto[h0:] - f[h0:]).mean() / max(float(f[h0:].mean()), 1e-12))
        return "bands " + " ".join(parts) + f"; per-pixel {err:.3f}"


def fit(
    species: tuple[str, ...],
    rounds: int,
    width: int,
    height: int,
    spp: int,
    tmp: Path,
    view: str = "fit",
    keys: tuple[str, ...] = ("medium", "low", "far"),
) -> None:
    """Fit each lower level's albedo factor (RGB) and sheen factor in a forest, on one view (``keys``: which;
    the far level's horizontal card, ``far_top``, is seen from above, on the ``aerial`` view).

    With the sheen off in both renders, the albedo factor g is updated by the truth over the automatic frame on
    the level's pixels (a fixed point: radiance grows slower than the albedo inside a canopy); with it on, the
    sheen's own radiance (with minus without) in each is matched by its weight.  Prints the recipe lines.
    """
    lib = ToneLibrary(tmp, species)
    case = ToneCase(lib, tmp, view, width, height, spp, keys)
    lib.set(sheen=False)
    plain_high = case.render("high_plain", LEVELS["high"])["rgb"]
    factors = {n: {lv: (np.ones(3), 1.0) for lv in keys} for n in species}
    for r in range(rounds + 1):
        lib.set(factors)
        auto = case.render(f"auto{r}")["rgb"]
        lib.set(factors, sheen=False)
        plain = case.render(f"plain{r}")["rgb"]
        for (name, level), m in case.masks.items():
            hs, hp, a, ap = (x[m].sum(axis=0) for x in (case.high["rgb"], plain_high, auto, plain))
            g, sh = factors[name][level]
            print(
                f"lod tone fit round {r} {name} {level} ({int(m.sum())} px): truth / automatic {np.round(hs / a, 3)}"
                f", without sheen {np.round(hp / ap, 3)}; factors albedo {np.round(g, 3)}, sheen {sh:.3f}",
                flush=True,
            )
            if r < rounds:
                sheen_own = float((a - ap).sum())
                sh = float(np.clip(sh * float((hs - hp).sum()) / sheen_own, 0.0, 4.0)) if sheen_own > 0 else sh
                factors[name][level] = (g * hp / np.maximum(ap, 1e-12), sh)
    for name in species:
        print(f"lod tone fit {name}: [lod_tone] (on top of the recipe's current tone)")
        for level in keys:
            g, sh = factors[name][level]
            t = lib.tone[name][level]
            a = [round(float(x) * y, 3) for x, y in zip(g, t["albedo"])]
            print(f"  {level} = {{ albedo = {a}, sheen = {round(sh * t['sheen'], 3)} }}")


def check(species: tuple[str, ...], width: int, height: int, spp: int, tmp: Path) -> None:
    """The recipes' tone against the levels without it, on the fit views and held-out ones (another light, another
    elevation)."""
    lib = ToneLibrary(tmp, species)
    for view in ("fit", "sunsky", "aerial", "oblique"):
        case = ToneCase(lib, tmp, view, width, height, spp)
        lib.set(lib.untoned())
        before = case.render("auto_untoned")["rgb"]
        lib.set()
        after = case.render("auto_toned")["rgb"]
        rb, ra = case.ratios(case.high["rgb"], before), case.ratios(case.high["rgb"], after)
        for key in case.masks:
            print(
                f"lod tone check {view} {key[0]} {key[1]} ({int(case.masks[key].sum())} px): truth / automatic "
                f"without tone {np.round(rb[key], 3)}, with {np.round(ra[key], 3)}"
            )
        print(f"lod tone check {view} frame without tone: {case.frame(before)}")
        print(f"lod tone check {view} frame with tone:    {case.frame(after)}")


#: The species whose recipes carry a [lod_tone] (the examples' trees).
TONED_SPECIES = ("broadleaf", "conifer", "birch", "pine", "palm")
#: Every tree high: the truth an example's automatic or distance-set levels are judged against.
ALL_HIGH = "lod.distances=[100000.0, 200000.0, 300000.0]"


def blocks(x: np.ndarray, k: int = 8) -> np.ndarray:
    """Means of ``k`` x ``k``-pixel blocks of an (H, W, 3) image (the region's tone, the noise averaged out)."""
    h, w = x.shape[0] // k * k, x.shape[1] // k * k
    return x[:h, :w].reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))


def examples(names: list[str], width: int, height: int, spp: int, tmp: Path) -> None:
    """Each example scene (configs/NAME.toml: its own light, haze, camera and [lod] distances; 640x360, 16 spp,
    not denoised, no motion blur) with its levels toned and without the tone, against every tree high: the
    frame's mean and six bands of rows, each over the truth's, and the relative mean difference of 8x8-pixel
    block means and of pixels."""
    lib = ToneLibrary(tmp, TONED_SPECIES, individuals_each=8)
    size: tuple[str, ...] = ("--width", str(width), "--height", str(height), "--spp", str(spp), "-q")
    size += ("--set", "render.denoise=false", "--set", "camera.shutter=0.0")
    for name in names:
        cfg = ROOT / "configs" / f"{name}.toml"
        lib.set()
        truth = render(cfg, tmp / f"{name}_truth.exr", env=lib.env, args=(*size, "--set", ALL_HIGH))["rgb"]
        toned = render(cfg, tmp / f"{name}_toned.exr", env=lib.env, args=size)["rgb"]
        lib.set(lib.untoned())
        untoned = render(cfg, tmp / f"{name}_untoned.exr", env=lib.env, args=size)["rgb"]
        lib.set()
        finite = np.isfinite(truth).all(-1) & np.isfinite(toned).all(-1) & np.isfinite(untoned).all(-1)
        truth, toned, untoned = (np.where(finite[..., None], x, 0.0) for x in (truth, toned, untoned))
        for tag, x in (("without tone", untoned), ("with tone", toned)):
            bands = [f"{r[0]:.3f}/{r[1]:.3f}/{r[2]:.3f}" for _, _, r in band_ratios(x, truth, 0, 6)]
            mean = x.mean(axis=(0, 1)) / truth.mean(axis=(0, 1))
            block = float(np.abs(blocks(x) - blocks(truth)).mean() / truth.mean())
            pixel = float(np.abs(x - truth).mean() / truth.mean())
            print(
                f"lod tone example {name} {tag}: frame {mean[0]:.3f}/{mean[1]:.3f}/{mean[2]:.3f}, 8x8 blocks "
                f"{block:.4f}, pixels {pixel:.3f}; bands " + " ".join(bands),
                flush=True,
            )
        if (~finite).any():
            print(f"lod tone example {name}: {int((~finite).sum())} pixel(s) not finite, left out")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--species", default="broadleaf,conifer,birch,pine")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--count", type=int, default=100_000)
    ap.add_argument("--angles", action=argparse.BooleanOptionalAction, default=True, help="the far level by elevation")
    ap.add_argument("--aerial", action="store_true", help="the forest case seen from 700 m up")
    ap.add_argument("--fit", default="", help="two species: fit their lower levels' tone in a forest and stop")
    ap.add_argument("--check", default="", help="two species: their recipes' tone against none, three views")
    ap.add_argument("--rounds", type=int, default=3, help="--fit: fixed-point rounds")
    ap.add_argument("--examples", default="", help="example scenes (demo,valley,...): toned/untoned vs every tree high")
    ap.add_argument("--view", default="fit", choices=("fit", "aerial"), help="--fit: the view fitted on")
    ap.add_argument("--keys", default="medium,low,far", help="--fit: the [lod_tone] entries fitted")
    ap.add_argument("--size", default="", help="--fit/--check: WIDTHxHEIGHT (960x540 fit, 640x360 check)")
    args = ap.parse_args()
    print(f"lod tone: {load_line()} at start")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if args.examples:
            examples([s.strip() for s in args.examples.split(",") if s.strip()], 640, 360, min(args.spp, 16), tmp)
            print(f"lod tone: {time.perf_counter() - t0:.0f} s; {load_line()} at end")
            return
        pair = tuple(s.strip() for s in (args.fit or args.check).split(",") if s.strip())
        if pair:
            if len(pair) != 2:
                raise SystemExit("--fit/--check take two species, e.g. broadleaf,conifer")
            size = args.size or ("960x540" if args.fit else "640x360")
            w, h = (int(x) for x in size.split("x"))
            if args.fit:
                keys = tuple(k.strip() for k in args.keys.split(",") if k.strip())
                fit(pair, args.rounds, w, h, min(args.spp, 16), tmp, args.view, keys)
            else:
                check(pair, w, h, min(args.spp, 16), tmp)
            print(f"lod tone: {time.perf_counter() - t0:.0f} s; {load_line()} at end")
            return
        trees([s.strip() for s in args.species.split(",") if s.strip()], args.spp, tmp)
        if args.angles:
            angles(args.spp, tmp)
        if args.count > 0:
            forest(args.count, args.spp, tmp, args.aerial)
    print(f"lod tone: {time.perf_counter() - t0:.0f} s; {load_line()} at end")


if __name__ == "__main__":
    main()
