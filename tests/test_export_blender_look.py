"""A fitted look exported to Blender renders in Cycles as forest renders it: numbers per region, not presence.

One tiny scene (flat ground, 18 block trees of three species, a constant sky and a sun, 96×54) is rendered
plain and with a fitted ``[lookdev]`` (a leaf tint on two species, a ground tint) by forest (forest_path,
``llvm_ad_rgb``) and by Cycles from the ``.blend`` export.  forest's ``species``, ``id`` and ``depth`` layers
cut the frame into regions (each species' trees, ground, sky); per region and channel the test compares

* the mean linear RGB, Cycles against forest (the renderers' shading models differ a little), and
* the fitted/plain ratio, Cycles' against forest's: this cancels the shading models, so it says whether the
  fitted tints moved both renders the same way.

Run twice: the ground as one material (``terrain_colour``, exported as a colour) and as ``[ground]`` rules
(an albedo grid, exported as a texture).  The tolerances and the figures measured are in docs/exports.md
("A fitted look travels"); ``FOREST_DOC_IMAGE=<png>`` writes the side-by-side picture shown there.
Skipped where no Blender is installed.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from forest.config import parse_config
from forest.export.blender import export_blender
from forest.images import read_image, srgb_to_linear, write_image
from forest.library.mesh import MeshData
from forest.render import render_scene
from forest.scene import load_scene

from export_support import FakeLod, FakePart, FakeSpecies, make_instances

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="Blender is not installed")

LEAF_TINT = (1.3, 0.8, 0.6)
GROUND_TINT = (0.7, 0.9, 1.2)
#: |Cycles / forest − 1| of a region's mean linear RGB, per channel (measured: at most 0.045).
MEAN_TOL = 0.08
#: |Cycles' fitted/plain ÷ forest's fitted/plain − 1| per region and channel (measured: at most 0.022).
RATIO_TOL = 0.04
SPP = 32
#: Every region, fitted: the hedge's leaf part is not ``tinted``, so the leaf tint leaves it alone everywhere.
FITTED_REGIONS = ("oak", "pine", "hedge", "ground", "sky")
FAR = 100000.0

SCENE = """
seed = 7
name = "fitted_look"
[terrain.flat]
size = 400.0
[[species]]
name = "broadleaf"
model = "oak"
percent = 34
[[species]]
model = "pine"
percent = 33
[[species]]
model = "hedge"
percent = 33
[camera]
position = [0.0, 28.0, -110.0]
target = [0.0, 8.0, 0.0]
fov = 50.0
far = {far}
[lights.sun]
elevation = 45.0
azimuth = 150.0
irradiance = 3.0
[lights.sky]
radiance = 0.4
colour = [0.6, 0.75, 1.0]
[render]
width = 96
height = 54
spp = {spp}
max_depth = 4
horizon_ground = false
view = "standard"
"""
ONE_COLOUR = "terrain_colour = [0.3, 0.25, 0.18]\n"
#: The fitted look: the broadleaf's leaves keyed by species name, the hedge's by model; the pine keeps its own.
LOOK = f"""
[lookdev]
ground_tint = {list(GROUND_TINT)}
[lookdev.leaf_tint]
broadleaf = {list(LEAF_TINT)}
hedge = {list(LEAF_TINT)}
"""


def block(lo, hi) -> MeshData:
    """A box with flat faces (four vertices per face, the face's normal), wound outward: both renderers shade
    it the same (a box with shared corner normals is shaded differently by each)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    verts, normals, faces = [], [], []
    for axis in range(3):
        u, w = (a for a in range(3) if a != axis)
        for side in (0.0, 1.0):
            n = np.zeros(3)
            n[axis] = 1.0 if side else -1.0
            quad = np.zeros((4, 3))
            quad[:, axis] = side
            quad[:, u] = (0, 1, 1, 0)
            quad[:, w] = (0, 0, 1, 1)
            quad = lo + quad * (hi - lo)
            outward = np.dot(np.cross(quad[1] - quad[0], quad[2] - quad[0]), n) > 0
            k = 4 * len(verts)
            faces += [[k, k + 1, k + 2], [k, k + 2, k + 3]] if outward else [[k, k + 2, k + 1], [k, k + 3, k + 2]]
            verts.append(quad)
            normals.append(np.tile(n, (4, 1)))
    v = np.concatenate(verts).astype(np.float32)
    return MeshData(v, np.array(faces, np.uint32), np.concatenate(normals).astype(np.float32), np.zeros((24, 2), "f4"))


#: Per species: its crown's box (metres), its leaves' colour and whether the leaf part is ``tinted``.
CROWNS = {
    "oak": (((-5, 4, -5), (5, 12, 5)), (0.25, 0.45, 0.15), True),
    "pine": (((-3, 3, -3), (3, 16, 3)), (0.12, 0.30, 0.14), True),
    "hedge": (((-6, 1, -2), (6, 5, 2)), (0.30, 0.40, 0.12), False),
}


class BlockLibrary:
    """``oak`` (a wide crown), ``pine`` (a tall one), ``hedge`` (a low one): a bark trunk and a leaf crown each,
    leaves translucent.  The hedge's leaf part is not ``tinted`` (the colour map leaves it alone)."""

    def __init__(self):
        self.species = {}
        for name, ((lo, hi), colour, tinted) in CROWNS.items():
            trunk = block((-0.5, 0, -0.5), (0.5, lo[1] + 1, 0.5))
            crown = block(lo, hi)
            parts = (
                FakePart("bark", Path(f"{name}_bark.ply"), (0.3, 0.2, 0.12), None, False, 0.0, trunk),
                FakePart("leaf", Path(f"{name}_leaf.ply"), colour, None, tinted, 0.3, crown),
            )
            pts = np.concatenate([trunk.vertices, crown.vertices]).astype(np.float64)
            lod = FakeLod("high", 24, np.stack([pts.min(0), pts.max(0)]), parts)
            self.species[name] = FakeSpecies(name, "generated", [lod])

    def names(self):
        return sorted(self.species)

    def resolve(self, model, base_dir=None):
        return self.species[model]


def trees():
    """18 upright trees turned about their axes, six of each species, spread over the middle of the frame; tint 1
    (no colour map)."""
    names = tuple(CROWNS)
    inst = make_instances(18, seed=2, partitions=("all",), empty_partition=None, species=names, tilt=0.0)
    rng = np.random.default_rng(2)
    inst.position[:] = np.stack([rng.uniform(-50, 50, 18), np.zeros(18), rng.uniform(-40, 40, 18)], 1)
    inst.species[:] = np.arange(18) % 3
    inst.scale[:] = rng.uniform(0.9, 1.2, 18)
    inst.tint[:] = 1.0
    return inst


def read_layers(path: Path) -> dict:
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    inp.close()
    return {name: data[..., k] for k, name in enumerate(spec.channelnames)}


def regions(layers: dict) -> dict[str, np.ndarray]:
    """Masks from forest's data layers: each species' trees, the ground (no tree, nearer than the far clip),
    the sky (at the far clip)."""
    species, tree, depth = layers["species.Z"], layers["id.Z"] >= 0, layers["depth.Z"]
    out = {name: tree & (species == k) for k, name in enumerate(CROWNS)}
    out["ground"] = ~tree & (depth < FAR)
    out["sky"] = ~tree & (depth >= FAR)
    return out


@pytest.fixture(scope="module", params=["colour", "rules"])
def renders(request, tmp_path_factory):
    """Both renderers, plain and fitted: the images (linear RGB), forest's region masks and the region means."""
    tmp = tmp_path_factory.mktemp(f"look_{request.param}")
    lib, inst = BlockLibrary(), trees()
    images = {}
    for look, extra in (("plain", ""), ("fitted", LOOK)):
        text = SCENE.format(far=FAR, spp=SPP) + (ONE_COLOUR if request.param == "colour" else "") + extra
        path = tmp / f"{look}.toml"
        path.write_text(text)
        scene = load_scene(parse_config(text, path=path), inst, library=lib)
        render_scene(scene, output=tmp / f"forest_{look}.exr", variant="llvm_ad_rgb")
        layers = read_layers(tmp / f"forest_{look}.exr")
        images["forest", look] = np.stack([layers["R"], layers["G"], layers["B"]], axis=-1)
        if look == "plain":
            masks = regions(layers)
        export_blender(scene, tmp / f"{look}.blend", render=tmp / f"cycles_{look}.png")
        images["cycles", look] = srgb_to_linear(read_image(tmp / f"cycles_{look}.png")[..., :3])
    means = {(r, look, name): images[r, look][m].mean(axis=0) for (r, look) in images for name, m in masks.items()}
    out = {"ground": request.param, "images": images, "masks": masks, "means": means}
    if os.environ.get("FOREST_DOC_IMAGE") and request.param == "colour":
        write_side_by_side(out, Path(os.environ["FOREST_DOC_IMAGE"]))
    return out


def write_side_by_side(r: dict, path: Path, zoom: int = 3) -> None:
    """forest | Cycles, plain above fitted, each pixel ``zoom``² (nearest), a 2-pixel white gutter."""
    im = r["images"]
    h, w, _ = im["forest", "plain"].shape
    gap = 2
    out = np.ones((2 * h * zoom + gap, 2 * w * zoom + gap, 3), np.float32)
    for row, look in enumerate(("plain", "fitted")):
        for col, renderer in enumerate(("forest", "cycles")):
            big = np.repeat(np.repeat(im[renderer, look], zoom, axis=0), zoom, axis=1)
            y, x = row * (h * zoom + gap), col * (w * zoom + gap)
            out[y : y + h * zoom, x : x + w * zoom] = big
    write_image(path, out)


def table(r: dict) -> str:
    lines = [
        f"ground as {r['ground']}: region pixels | mean forest, Cycles (plain; fitted) | fitted/plain forest, Cycles"
    ]
    m = r["means"]
    for name, mask in r["masks"].items():
        f0, c0, f1, c1 = (m[rend, look, name] for look in ("plain", "fitted") for rend in ("forest", "cycles"))
        lines.append(
            f"  {name:9} {int(mask.sum()):5} | {np.round(f0, 4)} {np.round(c0, 4)}; {np.round(f1, 4)} {np.round(c1, 4)}"
            f" | {np.round(f1 / f0, 3)} {np.round(c1 / c0, 3)}"
        )
    return "\n".join(lines)


def test_the_regions_are_in_view(renders):
    counts = {name: int(m.sum()) for name, m in renders["masks"].items()}
    assert min(counts.values()) >= 150, counts  # every region has pixels enough for its mean
    covered = np.sum([m for m in renders["masks"].values()], axis=0)
    assert np.all(covered == 1)  # the regions cut the frame


def test_region_means_match(renders):
    """Mean linear RGB per region, Cycles against forest, plain and fitted."""
    print(table(renders))
    m = renders["means"]
    worst = 0.0
    for look, names in (("plain", list(renders["masks"])), ("fitted", FITTED_REGIONS)):
        for name in names:
            rel = m["cycles", look, name] / m["forest", look, name] - 1.0
            worst = max(worst, float(np.abs(rel).max()))
            assert np.all(np.abs(rel) <= MEAN_TOL), (look, name, rel)
    print(f"  worst |Cycles / forest - 1| {worst:.3f}")


def ratios(r: dict, name: str) -> tuple[np.ndarray, np.ndarray]:
    m = r["means"]
    return tuple(m[rend, "fitted", name] / m[rend, "plain", name] for rend in ("forest", "cycles"))


@pytest.mark.parametrize("name", FITTED_REGIONS)
def test_the_fitted_look_moves_both_renders_alike(renders, name):
    """fitted/plain per region and channel: Cycles' agrees with forest's (the shading models cancel)."""
    forest, cycles = ratios(renders, name)
    print(f"{renders['ground']} {name}: fitted/plain forest {np.round(forest, 3)}, Cycles {np.round(cycles, 3)}")
    # the look did move forest's render: the tinted leaves and the ground most, the rest hardly (the hedge's
    # leaves are not tinted parts, and the leaf tint multiplies exactly the parts the colour map tints)
    want = {"oak": LEAF_TINT, "ground": GROUND_TINT}.get(name, (1.0, 1.0, 1.0))
    np.testing.assert_allclose(forest, want, atol=0.1 if name in ("oak", "ground") else 0.08)
    np.testing.assert_allclose(cycles / forest, 1.0, atol=RATIO_TOL)
