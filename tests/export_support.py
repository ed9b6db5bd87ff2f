"""Small scenes for the export tests: a config, a stand-in tree library and InstanceSets.

The stand-in library has the same interface as :mod:`forest.library` (species →
lods → parts with ``load()``) but builds its meshes in memory, so the export
tests neither build nor read the real tree cache.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from forest.config import parse_config
from forest.instances import InstanceSet, yaw_tilt_quaternion
from forest.library.mesh import MeshData


def _box(lo, hi, segments: int) -> MeshData:
    """A closed box split into ``segments`` slabs along Y (more triangles for higher levels)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ys = np.linspace(lo[1], hi[1], segments + 1)
    ring = np.array([[lo[0], lo[2]], [hi[0], lo[2]], [hi[0], hi[2]], [lo[0], hi[2]]])
    v = np.array([[x, y, z] for y in ys for x, z in ring])
    f = []
    for s in range(segments):
        a = 4 * s
        for k in range(4):
            i, j = a + k, a + (k + 1) % 4
            f += [[i, j, j + 4], [i, j + 4, i + 4]]
    top = 4 * segments
    f += [[0, 2, 1], [0, 3, 2], [top, top + 1, top + 2], [top, top + 2, top + 3]]
    v = v.astype(np.float32)
    n = v - v.mean(axis=0)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    uv = np.stack([(v[:, 0] - lo[0]) / (hi[0] - lo[0]), (v[:, 1] - lo[1]) / (hi[1] - lo[1])], 1)
    return MeshData(v, np.array(f, dtype=np.uint32), n.astype(np.float32), uv.astype(np.float32))


def _cards(centre_y: float, radius: float, count: int, seed: int) -> MeshData:
    """``count`` leaf cards (two triangles each) scattered in a crown."""
    rng = np.random.default_rng(seed)
    c = rng.normal(size=(count, 3)) * radius * 0.5 + np.array([0.0, centre_y, 0.0])
    d1 = rng.normal(size=(count, 3))
    d1 /= np.linalg.norm(d1, axis=1, keepdims=True)
    d2 = np.cross(d1, rng.normal(size=(count, 3)))
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    s = 0.3
    quad = np.stack([c - s * d1 - s * d2, c + s * d1 - s * d2, c + s * d1 + s * d2, c - s * d1 + s * d2], 1)
    v = quad.reshape(-1, 3).astype(np.float32)
    base = 4 * np.arange(count)[:, None]
    f = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.uint32)
    n = np.repeat(np.cross(d1, d2), 4, axis=0).astype(np.float32)
    uv = np.tile(np.array([[0, 1], [1, 1], [1, 0], [0, 0]], np.float32), (count, 1))
    return MeshData(v, f, n, uv)


@dataclass
class FakePart:
    kind: str
    path: Path
    colour: tuple
    texture: Path | None
    tinted: bool
    translucency: float
    mesh: MeshData
    sheen: float = 0.0  # leaves: the cuticle lobe's weight s (0: none)
    roughness: float = 0.0  # its GGX α

    def load(self) -> MeshData:
        return self.mesh


@dataclass
class FakeLod:
    name: str
    triangles: int
    bounds: np.ndarray
    parts: tuple


@dataclass
class FakeSpecies:
    name: str
    source: str
    lods: list


def fake_species(name: str, height: float, seed: int, levels=("high", "medium", "low", "far")) -> FakeSpecies:
    lods = []
    for k, lvl in enumerate(levels):
        bark = _box([-0.2, 0.0, -0.25], [0.2, height * 0.6, 0.25], max(1, 4 - k))
        leaf = _cards(height * 0.7, height * 0.3, max(2, 40 >> k), seed + k)
        parts = (
            FakePart("bark", Path(f"{name}_{lvl}_bark.ply"), (0.3, 0.2, 0.1), None, False, 0.0, bark),
            FakePart("leaf", Path(f"{name}_{lvl}_leaf.ply"), (0.2, 0.5, 0.1), None, True, 0.3, leaf),
        )
        pts = np.concatenate([bark.vertices, leaf.vertices]).astype(np.float64)
        lods.append(FakeLod(lvl, int(len(bark.faces) + len(leaf.faces)), np.stack([pts.min(0), pts.max(0)]), parts))
    return FakeSpecies(name, "generated", lods)


def leaf_texture(path: Path, size: int = 16) -> Path:
    """An RGBA leaf texture: a disk of alpha 1 in a transparent square, RGB a green ramp (8-bit sRGB PNG)."""
    from conftest import write_png

    y, x = (np.mgrid[0:size, 0:size] + 0.5) / size
    alpha = ((x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.16).astype(float)
    rgb = np.stack([0.3 + 0.5 * x, 0.6 + 0.3 * y, 0.2 + 0.0 * x], axis=2)
    return write_png(path, np.concatenate([rgb, alpha[..., None]], axis=2))


class FakeLibrary:
    """Species ``oak`` (four levels) and ``pine`` (two); with ``textures``, leaves carry :func:`leaf_texture`."""

    def __init__(self, textures: Path | None = None):
        self.species = {
            "oak": fake_species("oak", 12.0, 1),
            "pine": fake_species("pine", 18.0, 2, levels=("high", "low")),
        }
        if textures is not None:
            tex = leaf_texture(Path(textures) / "leaf.png")
            for sp in self.species.values():
                for lod in sp.lods:
                    lod.parts = tuple(dataclasses.replace(p, texture=tex) if p.kind == "leaf" else p for p in lod.parts)

    def names(self):
        return sorted(self.species)

    def resolve(self, model, base_dir=None):
        from forest.errors import ForestError

        if model not in self.species:
            raise ForestError(f"unknown tree model {model!r}")
        return self.species[model]


SCENE = """
seed = 7
name = "testwood"
[terrain.procedural]
size = 200.0
height = 20.0
resolution = 16
octaves = 3
[scatter]
count = 500
[[species]]
model = "oak"
percent = 60
[[species]]
model = "pine"
percent = 40
[camera]
position = [0.0, 40.0, -150.0]
target = [0.0, 5.0, 0.0]
fov = 50.0
[lights.sun]
elevation = 40.0
azimuth = 135.0
irradiance = 3.0
[lights.sky]
radiance = 0.4
[render]
width = 64
height = 48
spp = 4
"""


def make_config(tmp_path: Path, extra: str = "", name: str = "scene.toml", ground_material: bool = True):
    """The test scene + ``extra``; ``ground_material``: the ground is one material (``terrain_colour``), not the
    ``[ground]`` rules' albedo grid (which every export would write as a terrain texture)."""
    path = tmp_path / name
    one = "terrain_colour = [0.2, 0.18, 0.12]\n" if ground_material else ""
    path.write_text(SCENE + one + extra)
    return parse_config(path.read_text(), path=path)


def make_instances(
    n: int,
    seed: int = 3,
    partitions=("north", "south", "east"),
    species=("oak", "pine"),
    empty_partition: str | None = "east",
    tilt: float = 0.4,
) -> InstanceSet:
    """A random InstanceSet with tilted trees, varied scales and tints, partitions and species."""
    rng = np.random.default_rng(seed)
    pos = np.stack([rng.uniform(-100, 100, n), rng.uniform(0, 20, n), rng.uniform(-100, 100, n)], 1)
    yaw = rng.uniform(0, 2 * np.pi, n)
    normal = rng.normal(size=(n, 3)) * 0.3 + np.array([0, 1.0, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    rot = yaw_tilt_quaternion(yaw, normal, np.full(n, tilt))
    parts = list(partitions)
    allowed = [i for i, p in enumerate(parts) if p != empty_partition]
    return InstanceSet(
        id=np.sort(rng.choice(10 * n + 10, n, replace=False)).astype(np.uint64),
        position=pos,
        rotation=rot,
        yaw=yaw,
        scale=rng.uniform(0.6, 1.8, n),
        species=rng.integers(0, len(species), n),
        tint=rng.uniform(0.3, 1.3, (n, 3)),
        partition=rng.choice(allowed, n),
        normal=normal,
        phase=rng.uniform(0, 6.28, n),
        species_names=list(species),
        partition_names=parts,
        extent=(-100, -100, 100, 100),
        seed=seed,
    )


#: MaterialX standard-library nodes the exporters use.  usd-core is built without MaterialX's Sdr
#: plugin, so its validator reports them as missing from the shader registry; nothing else is excused.
MATERIALX_NODES = {
    "ND_UsdPreviewSurface_surfaceshader",
    "ND_geompropvalue_color3",
    "ND_geompropvalue_vector2",
    "ND_image_color4",
    "ND_convert_color4_color3",
    "ND_extract_color4",
    "ND_multiply_color3",
}


def validation_errors(stage) -> list[str]:
    """Every error usd-core's validators report (composition, types, stage metadata, shading…),
    except registry look-ups of the MaterialX nodes in :data:`MATERIALX_NODES`."""
    import re

    from pxr import UsdValidation

    ctx = UsdValidation.ValidationContext(UsdValidation.ValidationRegistry().GetOrLoadAllValidators())
    out = []
    for e in ctx.Validate(stage):
        m = re.match(r"shaderId '(\w+)' specified on shader prim .* not found in sdrRegistry", e.GetMessage())
        if e.GetName() == "MissingShaderIdInRegistry" and m and m.group(1) in MATERIALX_NODES:
            continue
        out.append(f"{e.GetName()}: {e.GetMessage()}")
    return out


def fly_keys(last_frame: int) -> str:
    """TOML for a two-key camera path from frame 1 to ``last_frame`` (the second key narrows the fov)."""
    return f"""
[[camera.keys]]
frame = 1
position = [0.0, 40.0, -150.0]
target = [0.0, 5.0, 0.0]
[[camera.keys]]
frame = {last_frame}
position = [60.0, 30.0, -120.0]
target = [10.0, 5.0, 0.0]
fov = 35.0
"""


def blender_probe(blend: Path, script: str, folder: Path) -> dict:
    """Run ``script`` (Python that writes a JSON object to ``sys.argv[-1]``) in Blender on the ``blend`` file and
    return that object."""
    import json
    import subprocess

    probe, out = folder / "probe.py", folder / "probe.json"
    probe.write_text(script)
    cmd = ["blender", "-b", str(blend), "--python-exit-code", "3", "--python", str(probe), "--", str(out)]
    subprocess.run(cmd, check=True, capture_output=True)
    return json.loads(out.read_text())
