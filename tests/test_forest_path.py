"""forest_path, forest's path tracer for the JIT variants: hits, layers, look, light, gradients, determinism.

Small scenes and tiny images; where an independent reference exists it is
the ``scalar_rgb`` renderer (Mitsuba's own surface interactions and BSDFs) or
a closed form.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_render import make_config, read_exr

from forest.instances import InstanceSet, yaw_tilt_quaternion
from forest.render import render_scene
from forest.render.path import Material, PathCamera, PathInputs, PathScene, SunLight, Surface
from forest.render.path.from_config import path_inputs

from render_fixtures import BoxLibrary

VARIANT = "llvm_ad_rgb"


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("pathlib"))


def forest_set(positions, species, names=("box", "card"), scale=1.0) -> InstanceSet:
    p = np.asarray(positions, np.float32)
    n = len(p)
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    return InstanceSet(
        id=np.arange(500, 500 + n),
        position=p,
        rotation=yaw_tilt_quaternion(np.zeros(n), up, np.zeros(n)),
        yaw=np.zeros(n),
        scale=np.full(n, scale),
        species=np.asarray(species),
        tint=np.ones((n, 3)),
        partition=np.zeros(n),
        normal=up,
        phase=np.zeros(n),
        species_names=list(names),
        extent=(-50.0, -50.0, 50.0, 50.0),
    )


def quad(y: float, half: float, *, up: bool = True):
    """A horizontal square at height y (normals up), as MeshData."""
    from forest.library.mesh import MeshData

    v = np.array([[-half, y, -half], [half, y, -half], [half, y, half], [-half, y, half]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]] if up else [[0, 1, 2], [0, 2, 3]], np.uint32)
    n = np.tile(np.array([[0.0, 1.0 if up else -1.0, 0.0]], np.float32), (4, 1))
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    return MeshData(v, f, n, uv)


def look(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    from forest.camera import look_at_matrix

    return look_at_matrix(position, target, up)


# ---------------------------------------------------------------------------
# Stage 1: hits rebuilt from preliminary intersections; depth, id, species
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("flatten", [0, 10_000])
def test_layers_match_the_scalar_renderer(tmp_path, library, flatten):
    """Instanced (flatten 0) or merged (10 000) trees: the id/species/depth layers agree with scalar_rgb's."""
    cfg = make_config(tmp_path, extra="[lod]\ndistances = [221.0, 222.0, 223.0]\n")
    pos = [[-20.0, 0.0, -20.0], [20.0, 0.0, -20.0], [-20.0, 0.0, 20.0], [20.0, 0.0, 22.0], [0.0, 0.0, 0.0]]
    inst = forest_set(pos, [0, 0, 0, 0, 1], scale=2.0)
    render_scene(cfg, output=tmp_path / "s.exr", instances=inst, variant="scalar_rgb", library=library)
    ref = read_exr(tmp_path / "s.exr")
    inputs = path_inputs(cfg, inst, library)
    inputs.flatten_triangles = flatten
    scene = PathScene(inputs, VARIANT)
    stats = scene.stats
    assert (stats.instances, stats.flattened_trees) == ((5, 0) if flatten == 0 else (0, 5))
    layers = scene.layers()
    # The LOD plan gave some trees the high box (6 m) and others the low one (3 m): both kinds are seen.
    assert set(np.unique(layers["id"]).astype(int)) == {-1, 500, 501, 502, 503, 504}
    same = layers["id"] == ref["id"]
    assert same.mean() > 0.99  # a pixel centre exactly on a box edge may go either way
    np.testing.assert_array_equal(layers["species"][same], ref["species"][same])
    hit = same & (ref["depth"] < 1e4)
    # The scalar depth is measured from the near plane (0.5 m in front of the camera), ours from the camera:
    # they differ by 0.5 / cos θ along a ray θ off the view axis.
    cam = inputs.camera
    forward = np.asarray(cam.to_world)[:3, 2]
    cos = np.array([[pixel_direction(cam, i, j) @ forward for j in range(cam.width)] for i in range(cam.height)])
    np.testing.assert_allclose(layers["depth"][hit], ref["depth"][hit] + 0.5 / cos[hit], atol=0.01)
    assert (layers["depth"][ref["depth"] >= 1e4] >= 1e4).all()


def pixel_direction(camera: PathCamera, i: int, j: int) -> np.ndarray:
    """Unit world direction of the ray through the centre of pixel (row i, column j) (pinhole, fov along x)."""
    t = np.tan(np.radians(camera.fov) / 2)
    x = (1 - 2 * (j + 0.5) / camera.width) * t  # camera +X is image left
    y = (1 - 2 * (i + 0.5) / camera.height) * t * camera.height / camera.width
    d = np.asarray(camera.to_world)[:3, :3] @ np.array([x, y, 1.0])
    return d / np.linalg.norm(d)


def test_layers_on_a_known_layout(library):
    """Straight down from 100 m: box tops, the card's opaque half and, through its transparent half, the ground."""
    inst = forest_set([[-8.0, 0.0, 0.0], [8.0, 0.0, 0.0]], [0, 1])
    camera = PathCamera(look([0.0, 100.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 30.0, 61, 61)
    inputs = PathInputs(
        instances=inst,
        species=[library.resolve("box"), library.resolve("card")],
        levels=np.array([3, 0]),  # the far box: 2×3×2 m
        matrices=inst.matrices(),
        camera=camera,
        surfaces=[Surface(quad(0.0, 15.0), Material("surface", (0.2, 0.2, 0.2)))],
        sun=SunLight((0.0, 1.0, 0.0), (1.0, 1.0, 1.0)),
    )
    layers = PathScene(inputs, VARIANT).layers()
    half = 100.0 * np.tan(np.radians(15.0))  # half the ground width seen at the image's centre row

    def pixel(x, z):  # the pixel looking at world (x, ·, z): image left is +X, image up is +Z
        return int(np.floor((1 - z / half) * 61 / 2)), int(np.floor((1 - x / half) * 61 / 2))

    def depth_at(i, j, height):
        d = pixel_direction(camera, i, j)
        return (100.0 - height) / -d[1]

    box, card_opaque, card_clear = pixel(-8.0, 0.0), pixel(11.0, 2.0), pixel(5.0, 2.0)
    assert layers["id"][box] == 500 and layers["species"][box] == 0
    assert layers["depth"][box] == pytest.approx(depth_at(*box, 3.0), abs=0.01)
    # The card (10×10 m at 5 m, centred on x = 8): its alpha is 0 for u < ½ (x < 8 m) and 1 beyond.
    assert layers["id"][card_opaque] == 501 and layers["species"][card_opaque] == 1
    assert layers["depth"][card_opaque] == pytest.approx(depth_at(*card_opaque, 5.0), abs=0.01)
    assert layers["id"][card_clear] == -1 and layers["species"][card_clear] == -1
    assert layers["depth"][card_clear] == pytest.approx(depth_at(*card_clear, 0.0), abs=0.01)
    # Outside the ground: nothing is hit, the far clip.
    assert layers["depth"][0, 0] == pytest.approx(1e5)
