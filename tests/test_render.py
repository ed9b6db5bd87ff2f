"""End-to-end renders of tiny forests in llvm_ad_rgb and scalar_rgb: presence, tints, LOD, motion, determinism."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from test_render_scene import ground_points

from forest.config import parse_config
from forest.errors import ForestError
from forest.images import srgb_to_linear
from forest.instances import InstanceSet, yaw_tilt_quaternion
from forest.render import choose_variant, render_scene
from forest.scene import load_scene

from render_fixtures import BoxLibrary

VARIANTS = ("scalar_rgb", "llvm_ad_rgb")

BASE = """
seed = 3
[terrain]
flat = {{ size = 100.0 }}
[maps]
{maps}
[camera]
{camera}
[lights]
sky = {{ radiance = 1.0, colour = [1.0, 1.0, 1.0] }}
[render]
width = 40
height = 40
spp = 4
terrain_colour = {ground}
{render}
[[species]]
model = "box"
percent = 100
"""


def write_png(path: Path, rgb: np.ndarray) -> Path:
    """An 8-bit image (values given in encoded [0, 1])."""
    data = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.UINT8)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(data)
    out.close()
    return path


TOP_DOWN_CAMERA = "position = [0.0, 220.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\nfov = 28.0\n"


def make_config(
    tmp_path: Path,
    *,
    maps: str = "",
    camera: str = "",
    render: str = "",
    extra: str = "",
    replace_camera: bool = False,
    ground: str = "[0.1, 0.1, 0.1]",
):
    camera = camera if replace_camera else TOP_DOWN_CAMERA + camera
    text = BASE.format(maps=maps, camera=camera, render=render, ground=ground) + extra
    if "[lod]" not in extra:
        # These scenes test colours of the box species' highest level: the automatic level of detail would pick
        # its far level at these small image sizes.
        text += "\n[lod]\nauto = false\n"
    (tmp_path / "scene.toml").write_text(text)
    return parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)


def read_exr(path: Path) -> dict:
    inp = oiio.ImageInput.open(str(path))
    spec = inp.spec()
    data = np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float")).reshape(spec.height, spec.width, -1)
    attrs = {a.name: a.value for a in spec.extra_attribs}
    inp.close()
    names = list(spec.channelnames)
    return {
        "rgb": data[..., :3],
        "depth": data[..., names.index("depth.Z")],
        "id": data[..., names.index("id.Z")],
        "species": data[..., names.index("species.Z")],
        "attrs": attrs,
    }


def trees(positions, *, phase=None, names=("box",), scale=1.0) -> InstanceSet:
    p = np.asarray(positions, np.float32)
    n = len(p)
    up = np.tile([0.0, 1.0, 0.0], (n, 1))
    return InstanceSet(
        id=np.arange(100, 100 + n),
        position=p,
        rotation=yaw_tilt_quaternion(np.zeros(n), up, np.zeros(n)),
        yaw=np.zeros(n),
        scale=np.full(n, scale),
        species=np.zeros(n),
        tint=np.ones((n, 3)),
        partition=np.zeros(n),
        normal=up,
        phase=np.zeros(n) if phase is None else phase,
        species_names=list(names),
        extent=(-50.0, -50.0, 50.0, 50.0),
    )


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return BoxLibrary(tmp_path_factory.mktemp("boxlib"))


@pytest.mark.parametrize("variant", VARIANTS)
def test_trees_appear_where_presence_allows(tmp_path, library, variant):
    """Presence map white for x < 0 only: trees render there and nowhere else."""
    from forest.scatter import scatter

    presence = np.zeros((8, 8, 3))
    presence[:, :4] = 1.0  # columns 0–3: x < 0
    write_png(tmp_path / "presence.png", presence)
    cfg = make_config(tmp_path, maps='presence = "presence.png"', extra="[scatter]\ncount = 300\n")
    inst, _ = scatter(cfg, library=library)
    assert len(inst) > 20 and (inst.position[:, 0] < 0.5).all()
    res = render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "f.exr", variant=variant)
    out = read_exr(tmp_path / "f.exr")
    gx, gz = ground_points(cfg, 40, 40)
    inside = (np.abs(gz) < 45) & (np.abs(gx) < 45)
    allowed, banned = inside & (gx < -3), inside & (gx > 4)
    tree_px = out["id"] >= 0
    assert tree_px[allowed].mean() > 0.1  # plenty of trees where allowed
    assert not tree_px[banned].any()  # none where presence is 0
    # where trees are banned the beauty pass is bare terrain: albedo 0.1 under a white sky
    np.testing.assert_allclose(out["rgb"][banned].mean(axis=0), [0.1, 0.1, 0.1], atol=0.02)
    assert out["rgb"][allowed & tree_px].mean() > 0.2  # white boxes: twice as bright as the ground
    ids = set(np.unique(out["id"][tree_px]).astype(int).tolist())
    assert ids <= set(inst.id.astype(int).tolist())
    assert res.trees == len(inst) and res.variant == variant
    assert (tmp_path / "f.png").is_file()


@pytest.mark.parametrize("variant", VARIANTS)
def test_colour_map_tints_each_tree_where_it_stands(tmp_path, library, variant):
    """Colour map red for z < 0, green for z > 0: a tree's pixels take the colour of its own half."""
    colour = np.zeros((8, 8, 3))
    colour[:4] = [1.0, 0.25, 0.25]
    colour[4:] = [0.25, 1.0, 0.25]
    write_png(tmp_path / "colour.png", colour)
    # direct light only; a black ground (the ground is one untinted material) adds nothing to the edge pixels
    cfg = make_config(tmp_path, maps='colour = "colour.png"', render="max_depth = 2", ground="[0.0, 0.0, 0.0]")
    pos = [[x, 0.0, z] for x in (-30.0, -10.0, 10.0, 30.0) for z in (-30.0, -15.0, 15.0, 30.0)]
    # A set made elsewhere keeps its tints (forest.scene); these trees carry the map's tint where they stand,
    # as a scattered set does, and every renderer shows it by looking the map up at each hit.
    inst = trees(pos)
    scene = load_scene(cfg, inst, library=library)
    inst = dataclasses.replace(inst, tint=scene.colour.at(inst.position[:, 0], inst.position[:, 2]))
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "t.exr", variant=variant)
    out = read_exr(tmp_path / "t.exr")
    z_of_id = dict(zip(inst.id.astype(int).tolist(), inst.position[:, 2].tolist()))
    ids = out["id"].astype(int)
    hit = ids >= 0
    z = np.array([z_of_id.get(i, 0.0) for i in ids[hit]])
    rgb = out["rgb"][hit]
    south, north = rgb[z < 0].mean(axis=0), rgb[z > 0].mean(axis=0)
    assert south[0] > 2.5 * south[1] and north[1] > 2.5 * north[0]
    # Exact per hit: reflectance = albedo × the map's linear colour, so the channel ratio is the map's
    # (sRGB 1.0 / 0.25 → linear 1 / 0.0509), however much of the pixel the grey-lit box covers.
    ratio = 1.0 / float(srgb_to_linear(np.array([0.25]))[0])
    assert south[0] / south[1] == pytest.approx(ratio, rel=0.05)
    assert north[1] / north[0] == pytest.approx(ratio, rel=0.05)


@pytest.mark.parametrize("variant", VARIANTS)
def test_lod_switches_with_camera_distance(tmp_path, library, variant):
    """LOD high is a white 2×6×2 box, far a small blue one: a tree's look follows its distance."""
    cam = (
        "keys = [ { frame = 1, position = [0.0, 120.0, -60.0], target = [0.0, 0.0, 0.0], fov = 45.0 }, "
        "{ frame = 2, position = [0.0, 120.0, 60.0], target = [0.0, 0.0, 0.0], fov = 45.0 } ]"
    )
    cfg = make_config(tmp_path, camera=cam, extra="[lod]\ndistances = [130.0, 135.0, 140.0]\n")
    inst = trees([[0.0, 0.0, -35.0], [0.0, 0.0, 35.0]], scale=4.0)  # south tree, north tree
    res = render_scene(
        load_scene(cfg, inst, library=library),
        output=tmp_path / "l_####.exr",
        variant=variant,
        frames=[1, 2],
    )
    assert res.lod_counts == {"high": 2, "far": 2}
    for frame, near_id in ((1, 100), (2, 101)):
        out = read_exr(tmp_path / f"l_{frame:04d}.exr")
        near = out["rgb"][out["id"] == near_id].mean(axis=0)
        far = out["rgb"][out["id"] == 201 - near_id].mean(axis=0)
        assert abs(near[0] - near[2]) < 0.1 and near[0] > 0.4  # white box close to the camera
        assert far[2] > 3 * far[0]  # blue stand-in far away
        assert (out["id"] == near_id).sum() > (out["id"] == 201 - near_id).sum()
    assert "high=1" in read_exr(tmp_path / "l_0001.exr")["attrs"]["forest:lod"]


@pytest.mark.parametrize("variant", VARIANTS)
def test_subframes_differ_when_the_camera_moves(tmp_path, library, variant):
    """Motion blur averages sub-frames: with a moving camera it smears the image, with a still one it does not."""
    inst = trees([[x, 0.0, 0.0] for x in (-20.0, 0.0, 20.0)], scale=4.0)
    moving = (
        "keys = [ { frame = 1, position = [-30.0, 220.0, 0.0], target = [-30.0, 0.0, 1.0] }, "
        "{ frame = 3, position = [30.0, 220.0, 0.0], target = [30.0, 0.0, 1.0] } ]\nshutter = 1.0"
    )
    images = {}
    for name, cam, _shutter in (
        ("sharp", moving.replace("shutter = 1.0", "shutter = 0.0"), 0.0),
        ("blur", moving, 1.0),
    ):
        cfg = make_config(tmp_path, camera=cam, render="subframes = 4")
        render_scene(
            load_scene(cfg, inst, library=library), output=tmp_path / f"{name}.exr", variant=variant, frames=[2]
        )
        images[name] = read_exr(tmp_path / f"{name}_0002.exr")["rgb"].mean(axis=2)
    sharp, blur = images["sharp"][8:32, 8:32], images["blur"][8:32, 8:32]  # inside the terrain, no sky
    # The blurred frame's bright boxes are smeared along X: more pixels partly lit, a lower peak.
    assert (blur > 0.2).sum() > (sharp > 0.2).sum()
    assert blur.max() < sharp.max()
    # Frames 1 and 3 of the moving camera see different things.
    cfg = make_config(tmp_path, camera=moving.replace("shutter = 1.0", ""))
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "m_#.exr", variant=variant, frames="1,3")
    a, b = read_exr(tmp_path / "m_1.exr"), read_exr(tmp_path / "m_3.exr")
    assert not np.array_equal(a["id"], b["id"])


def test_wind_moves_trees_between_frames(tmp_path, library):
    cam = "position = [0.0, 8.0, -30.0]\ntarget = [0.0, 4.0, 0.0]"
    cfg = make_config(
        tmp_path, camera=cam, replace_camera=True, extra="[wind]\nstrength = 10.0\nfrequency = 1.0\ndirection = 90.0\n"
    )
    inst = trees([[0.0, 0.0, 0.0], [6.0, 0.0, 4.0]], phase=np.array([0.0, 1.5], np.float32))
    render_scene(
        load_scene(cfg, inst, library=library), output=tmp_path / "w_#.exr", variant="scalar_rgb", frames=[1, 7]
    )
    a, b = read_exr(tmp_path / "w_1.exr"), read_exr(tmp_path / "w_7.exr")
    assert not np.array_equal(a["id"] >= 0, b["id"] >= 0)
    calm = make_config(tmp_path, camera=cam, replace_camera=True)
    render_scene(
        load_scene(calm, inst, library=library),
        output=tmp_path / "c_#.exr",
        variant="scalar_rgb",
        frames=[1, 7],
    )
    a, b = read_exr(tmp_path / "c_1.exr"), read_exr(tmp_path / "c_7.exr")
    assert np.array_equal(a["id"], b["id"]) and np.array_equal(a["depth"], b["depth"])


@pytest.mark.parametrize("variant", VARIANTS)
def test_same_config_and_seed_give_identical_files(tmp_path, library, variant):
    colour = np.zeros((4, 4, 3))
    colour[..., 0] = np.linspace(0.2, 1.0, 4)
    colour[..., 1] = 0.6
    write_png(tmp_path / "colour.png", colour)
    cfg = make_config(tmp_path, maps='colour = "colour.png"')
    inst = trees([[x, 0.0, z] for x in (-20.0, 0.0, 20.0) for z in (-20.0, 20.0)])
    digests = []
    for k in range(2):
        render_scene(load_scene(cfg, inst, library=library), output=tmp_path / f"d{k}.exr", variant=variant)
        digests.append(tuple(hashlib.sha256((tmp_path / f"d{k}.{e}").read_bytes()).hexdigest() for e in ("exr", "png")))
    assert digests[0] == digests[1]
    attrs = read_exr(tmp_path / "d0.exr")["attrs"]
    assert attrs["forest:trees"] == 6 and attrs["forest:variant"] == variant
    assert attrs["forest:instanced_triangles"] == 6 * 12 and attrs["forest:spp"] == 4
    other = make_config(tmp_path, maps='colour = "colour.png"', render="seed = 5")
    render_scene(load_scene(other, inst, library=library), output=tmp_path / "d2.exr", variant=variant)
    assert (tmp_path / "d2.exr").read_bytes() != (tmp_path / "d0.exr").read_bytes()


@pytest.mark.parametrize("variant", VARIANTS)
def test_haze_and_depth(tmp_path, library, variant):
    """Uniform haze (H ≫ the scene) of a known colour over a grey ground seen from 220 m:
    L = L₀·e^(−σd) + C·(1 − e^(−σd)) at every ground pixel, in both renderers (forest_path per path
    segment, scalar_rgb as a post-process), with d the depth layer."""
    haze = "haze = 0.01\nhaze_height = 100000.0\nhaze_anisotropy = 0.0\nhaze_colour = [1.0, 0.0, 0.0]\nmax_depth = 2"
    cfg = make_config(tmp_path, render=haze)
    render_scene(
        load_scene(cfg, trees([[0.0, 0.0, 0.0]], scale=3.0), library=library),
        output=tmp_path / "h.exr",
        variant=variant,
    )
    out = read_exr(tmp_path / "h.exr")
    from scipy.ndimage import binary_dilation

    ground = ~binary_dilation(out["id"] >= 0, iterations=1)  # pixels wholly on the ground
    # The ground runs on past the terrain's edge: every pixel sees it, ~220 m away (more towards the corners).
    assert ground.any() and (out["depth"][ground] > 219.0).all() and (out["depth"][ground] < 240.0).all()
    t = np.exp(-0.01 * out["depth"][ground])
    np.testing.assert_allclose(out["rgb"][ground][:, 0], 0.1 * t + (1 - t), atol=0.01)
    np.testing.assert_allclose(out["rgb"][ground][:, 1], 0.1 * t, atol=0.01)
    tree = out["id"] >= 0
    assert out["depth"][tree].max() < out["depth"][ground].min()  # the box top is nearer than the ground


def test_haze_thins_with_height_as_its_closed_form_integral(tmp_path, library):
    """A ground seen straight down through a haze of scale height 50 m: the transmittance is exp(−∫σ(y)dy),
    checked against a numerical integral of σ₀·e^(−y/H) from the camera down to the ground."""
    haze = "haze = 0.02\nhaze_height = 50.0\nhaze_anisotropy = 0.0\nhaze_colour = [0.0, 0.0, 1.0]\nmax_depth = 2"
    cfg = make_config(tmp_path, render=haze)
    render_scene(load_scene(cfg, trees(np.zeros((0, 3))), library=library), output=tmp_path / "f.exr")
    out = read_exr(tmp_path / "f.exr")
    centre = out["rgb"][18:22, 18:22].reshape(-1, 3).mean(axis=0)
    y = np.linspace(0.0, 220.0, 200_001)
    tau = np.trapezoid(0.02 * np.exp(-y / 50.0), y)
    t = np.exp(-tau)
    np.testing.assert_allclose(centre, [0.1 * t, 0.1 * t, 0.1 * t + (1.0 - t)], atol=0.004)


def test_bad_input(tmp_path, library):
    cfg = make_config(tmp_path)
    inst = trees([[0.0, 0.0, 0.0]])
    with pytest.raises(ForestError, match=r"\.exr"):
        render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "x.jpg", variant="scalar_rgb")
    with pytest.raises(ForestError, match="variant"):
        render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "x.exr", variant="metal_rgb")
    with pytest.raises(ForestError, match="unknown species"):
        render_scene(
            load_scene(
                cfg.with_overrides({"species[0].model": "oak"}), trees([[0, 0, 0]], names=("oak",)), library=library
            ),
            output=tmp_path / "x.exr",
            variant="scalar_rgb",
        )
    with pytest.raises(ForestError, match="frames"):
        render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "x.exr", frames="5-1")
    with pytest.raises(ForestError, match=r"transmittance.*unknown key"):
        render_scene(
            load_scene(cfg.with_overrides({"lights.sky.transmittance": 1.0}), inst, library=library),
            output=tmp_path / "x.exr",
            variant="scalar_rgb",
        )
    assert not list(tmp_path.glob("x*"))


def test_default_variant_choice(monkeypatch, fake_gpu):
    """forest_path on the CPU by default, on the GPU where there is one that passed its self-check (faked here;
    tests/test_selfcheck.py has the rest); a request or the config wins."""
    import forest.render.variant as variant

    monkeypatch.setattr(variant, "cuda_available", lambda: False)
    v, why = choose_variant(130_000)
    assert v == "llvm_ad_rgb" and "forest_path" in why and len(why) < 100
    monkeypatch.setattr(variant, "cuda_available", lambda: True)
    assert choose_variant(130_000)[0] == "cuda_ad_rgb" and len(fake_gpu.calls) == 1
    assert choose_variant(10, "llvm_ad_rgb") == ("llvm_ad_rgb", "requested")
    assert choose_variant(10, None, "scalar_rgb") == ("scalar_rgb", "[render] variant")
    monkeypatch.setattr(variant, "cuda_available", lambda: False)
    with pytest.raises(ForestError, match=r"variant: cuda_ad_rgb needs an NVIDIA GPU"):
        choose_variant(10, "cuda_ad_rgb")


def test_empty_forest_renders_the_terrain(tmp_path, library):
    cfg = make_config(tmp_path)
    res = render_scene(
        load_scene(cfg, trees(np.zeros((0, 3))), library=library),
        output=tmp_path / "e.exr",
        variant="scalar_rgb",
    )
    out = read_exr(tmp_path / "e.exr")
    assert res.trees == 0 and res.instanced_triangles == 0 and (out["id"] == -1).all()
    gx, gz = ground_points(cfg, 40, 40)
    inside = (np.abs(gx) < 45) & (np.abs(gz) < 45)
    np.testing.assert_allclose(out["rgb"][inside].mean(axis=0), [0.1, 0.1, 0.1], atol=0.01)


@pytest.mark.parametrize("variant", VARIANTS)
def test_leaf_card_alpha(tmp_path, library, variant):
    """A card whose texture alpha is 0 on one half: the id pass and the camera see through that half,
    and with alpha_shadows the sun straight above lights the ground through it."""
    sun = "sun = { elevation = 90.0, azimuth = 0.0, irradiance = 3.0, colour = [1.0, 1.0, 1.0] }\n"
    inst = trees([[0.0, 0.0, 0.0]], names=("card",), scale=3.0)  # 30 × 30 m card, 15 m up
    ground = {}
    for alpha_shadows in ("false", "true"):
        text = BASE.format(
            maps="",
            camera=TOP_DOWN_CAMERA,
            render=f"alpha_shadows = {alpha_shadows}\nmax_depth = 2",
            ground="[0.1, 0.1, 0.1]",
        )
        text = text.replace("[lights]\n", "[lights]\n" + sun).replace('model = "box"', 'model = "card"')
        (tmp_path / "card.toml").write_text(text)
        cfg = parse_config(text, path=tmp_path / "card.toml", base_dir=tmp_path)
        render_scene(
            load_scene(cfg, inst, library=library), output=tmp_path / f"c_{alpha_shadows}.exr", variant=variant
        )
        out = read_exr(tmp_path / f"c_{alpha_shadows}.exr")
        gx, gz = ground_points(cfg, 40, 40)
        under = (np.abs(gx) < 12) & (np.abs(gz) < 12)  # well inside the card's shadow
        seen = out["id"][under] >= 0
        assert 0.3 < seen.mean() < 0.7  # half the card is cut away
        assert (out["depth"][under][~seen] > out["depth"][under][seen].max()).all()
        ground[alpha_shadows] = out["rgb"][under][~seen].mean()
    # Ground seen through the cut-out: sky only when shadow rays stop at the whole card (Mitsuba's
    # path), sun + sky (ρ·E/π = 0.1·3/π ≈ 0.095 more) when they honour the alpha (volpath; forest_path always).
    if variant == "scalar_rgb":
        assert ground["true"] - ground["false"] > 0.07
    else:
        assert ground["true"] == ground["false"] and ground["true"] > 0.07 + 0.1 * 0.9


def count_builds(monkeypatch) -> list[int]:
    """A list that grows by one with every forest_path scene build (``TraversalScene``) from now on."""
    import forest.render.path.frame as path_frame

    builds: list[int] = []
    build = path_frame.TraversalScene

    def counted(*a, **kw):
        builds.append(1)
        return build(*a, **kw)

    monkeypatch.setattr(path_frame, "TraversalScene", counted)
    return builds


def test_a_wind_blurred_frame_builds_one_scene_per_pose(tmp_path, library, monkeypatch):
    """When every sub-frame needs its own wind pose (here forced: no sway is small enough to share one),
    forest_path's renderer is built in the pose of the first sub-frame the frame loop renders (farthest from the
    centre), so K sub-frames cost K scene builds, not K + 1, and the frame is the same as when the renderer was
    built in the centre's pose."""
    import forest.render.jit_frame as jit_frame
    import forest.render.loop as loop
    from forest.render.loop import first_pose_time, subframe_order

    monkeypatch.setattr(loop, "POSE_PIXELS", 1e-12)
    assert subframe_order([0.5, 1.0, 1.5], 1.0) == [0, 2, 1]  # the centre last
    cam = "position = [0.0, 8.0, -30.0]\ntarget = [0.0, 4.0, 0.0]\nshutter = 1.0"
    cfg = make_config(
        tmp_path,
        camera=cam,
        replace_camera=True,
        render="subframes = 3",
        extra="[wind]\nstrength = 10.0\nfrequency = 1.0\ndirection = 90.0\n",
    )
    inst = trees([[0.0, 0.0, 0.0], [6.0, 0.0, 4.0]], phase=np.array([0.0, 1.5], np.float32))
    scene = load_scene(cfg, inst, library=library)
    t = first_pose_time(scene, 1.0, 3, 40, 40)  # an end of the shutter (which end: the float tie-break of the order)
    assert t * 24.0 == pytest.approx(1.0 - 1.0 / 3.0) or t * 24.0 == pytest.approx(1.0 + 1.0 / 3.0)
    builds = count_builds(monkeypatch)
    render_scene(scene, output=tmp_path / "now.exr", variant="llvm_ad_rgb")
    assert len(builds) == 3
    builds.clear()
    monkeypatch.setattr(jit_frame, "first_pose_time", lambda scene, frame, subframes, w, h: frame / 24.0)
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "centre.exr", variant="llvm_ad_rgb")
    assert len(builds) == 4  # built in the centre's pose, then three sub-frames
    np.testing.assert_array_equal(read_exr(tmp_path / "now.exr")["rgb"], read_exr(tmp_path / "centre.exr")["rgb"])


def _sway_scene(tmp_path, library, *, strength: float, camera_z1: float | None = None, width: int = 400):
    """One 6 m box 20 m in front of the camera (fov 40°), the wind across the view, 5 sub-frames over a whole
    frame's shutter at 24 fps; ``camera_z1``: the camera moves along X to there by frame 2."""
    if camera_z1 is None:
        cam = "position = [0.0, 3.0, -20.0]\ntarget = [0.0, 3.0, 0.0]\nfov = 40.0\nshutter = 1.0\n"
    else:
        cam = (
            "fov = 40.0\nshutter = 1.0\nkeys = [\n"
            "  { frame = 1, position = [0.0, 3.0, -20.0], target = [0.0, 3.0, 0.0] },\n"
            f"  {{ frame = 2, position = [{camera_z1}, 3.0, -20.0], target = [{camera_z1}, 3.0, 0.0] }},\n]\n"
        )
    text = BASE.format(maps="", camera=cam, render="subframes = 5", ground="[0.1, 0.1, 0.1]")
    text = text.replace("width = 40\nheight = 40", f"width = {width}\nheight = {width}")
    text += f"[wind]\nstrength = {strength}\nfrequency = 2.0\ndirection = 90.0\n[lod]\nauto = false\n"
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    return cfg, load_scene(cfg, trees([[0.0, 0.0, 0.0]], phase=np.array([0.3], np.float32)), library=library)


def test_a_frame_measures_its_wind_poses_once(tmp_path, library, monkeypatch):
    """forest_path's renderer is built in the first pose its frame loads and the frame loop then poses the frame:
    both ask :func:`forest.render.loop.pose_times` for that frame's poses, which projects every tree twice, and
    the second asks again for nothing. Another frame size is another question."""
    import forest.render.loop as loop
    from forest.camera import subframe_times

    _, scene = _sway_scene(tmp_path, library, strength=2.0, width=40)
    calls: list[int] = []
    real = loop.pose_count
    monkeypatch.setattr(loop, "pose_count", lambda *a: calls.append(1) or real(*a))
    render_scene(scene, output=tmp_path / "f.exr", variant="llvm_ad_rgb")
    assert len(calls) == 1
    times = subframe_times(1.0, 1.0, 5)
    bigger = loop.pose_times(scene, 1.0, times, 80, 80)
    assert len(calls) == 2 and loop.pose_times(scene, 1.0, times, 80, 80) == bigger and len(calls) == 2


def test_a_frame_rendered_alone_builds_its_scene_once(tmp_path, library, monkeypatch):
    """A render of frame 5 alone (a render farm's task) builds forest_path's scene in frame 5's pose, once — it
    had been built in frame 1's and then again — and the frame is the one a render of frames 4-5 writes."""
    cam = (
        "fov = 40.0\nkeys = [\n  { frame = 1, position = [0.0, 3.0, -40.0], target = [0.0, 3.0, 0.0] },\n"
        "  { frame = 9, position = [0.0, 3.0, -8.0], target = [0.0, 3.0, 30.0] },\n]\n"
    )
    cfg = make_config(tmp_path, camera=cam, replace_camera=True, extra="[lod]\ndistances = [20.0, 60.0, 200.0]\n")
    inst = trees([[0.0, 0.0, 0.0], [4.0, 0.0, 10.0], [-5.0, 0.0, 25.0]])
    builds = count_builds(monkeypatch)
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "one_####.exr", frames=[5],
                 variant="llvm_ad_rgb")  # fmt: skip
    assert len(builds) == 1
    builds.clear()
    render_scene(load_scene(cfg, inst, library=library), output=tmp_path / "two_####.exr", frames=[4, 5],
                 variant="llvm_ad_rgb")  # fmt: skip
    np.testing.assert_array_equal(
        read_exr(tmp_path / "one_0005.exr")["rgb"], read_exr(tmp_path / "two_0005.exr")["rgb"]
    )


def test_a_frame_is_the_same_whatever_was_rendered_before_it(tmp_path):
    """Frame 5 rendered alone and after frame 1 in the same process are the same bytes, though frame 1 sees the
    broadleaves close (their highest level, single-leaf textures) and frame 5 from afar (other levels, other
    textures): every texture of the scene is in the atlas from the start, in one order
    (``forest.render.path.geometry``), so what was built before does not shift the atlas a frame reads."""
    cam = (
        "fov = 40.0\nkeys = [\n  { frame = 1, position = [0.0, 4.0, -25.0], target = [0.0, 4.0, 0.0] },\n"
        "  { frame = 5, position = [0.0, 40.0, -400.0], target = [0.0, 4.0, 0.0] },\n]\n"
    )
    text = BASE.format(maps="", camera=cam, render="", ground="[0.1, 0.1, 0.1]").replace('"box"', '"broadleaf"')
    text += "[lod]\ndistances = [60.0, 150.0, 300.0]\n"
    cfg = parse_config(text, path=tmp_path / "scene.toml", base_dir=tmp_path)
    inst = trees([[0.0, 0.0, 0.0], [8.0, 0.0, 12.0], [-9.0, 0.0, 20.0]], names=("broadleaf",))
    render_scene(load_scene(cfg, inst), output=tmp_path / "alone_####.exr", frames=[5], variant="llvm_ad_rgb")
    render_scene(load_scene(cfg, inst), output=tmp_path / "after_####.exr", frames=[1, 5], variant="llvm_ad_rgb")
    first, alone = read_exr(tmp_path / "after_0001.exr"), read_exr(tmp_path / "alone_0005.exr")
    assert first["attrs"]["forest:lod"] != alone["attrs"]["forest:lod"]  # other levels in the two frames
    np.testing.assert_array_equal(alone["rgb"], read_exr(tmp_path / "after_0005.exr")["rgb"])


def test_sub_frames_share_a_wind_pose_when_the_sway_is_small(tmp_path, library, monkeypatch):
    """The sub-frames share m poses (forest.render.loop, step 2): the box's top sways across the view by
    f·H·2|sin(Δθ/2)|/d pixels between the first and last sub-frame (θ(t) = A sin(2πft + φ), a pinhole's
    closed form, not the code's projection), and m = ⌈that / 1 px⌉ when the camera stands still — here 2 of 5,
    in runs posed at their mean times; a weaker wind shares one pose at the frame's centre (one scene build for
    the frame, the image within noise of five poses'); a camera that moves the box by more than its sway
    between two sub-frames shares one pose too."""
    import math

    import forest.render.loop as loop
    from forest.camera import subframe_times
    from forest.render.loop import pose_count, pose_times, subframe_order

    times = subframe_times(1.0, 1.0, 5)

    def expected(strength: float) -> float:
        theta = [math.radians(strength) * math.sin(2 * math.pi * 2.0 * t / 24.0 + 0.3) for t in (times[0], times[-1])]
        f_px = 200.0 / math.tan(math.radians(20.0))
        return f_px * 6.0 * 2 * abs(math.sin((theta[1] - theta[0]) / 2)) / 20.0

    _, scene = _sway_scene(tmp_path, library, strength=2.0)
    m = math.ceil(expected(2.0))
    assert 1 < m < 5 and pose_count(scene, 1.0, times, 400, 400) == m
    poses = pose_times(scene, 1.0, times, 400, 400)
    runs = sorted(set(poses))
    assert len(runs) == m and poses == sorted(poses)  # contiguous runs in time order
    for r in runs:
        assert r == pytest.approx(np.mean([t for t, q in zip(times, poses) if q == r]))
    order = subframe_order(times, 1.0, poses)
    assert sum(poses[a] != poses[b] for a, b in itertools.pairwise(order)) == m - 1  # each run rendered together

    _, weak = _sway_scene(tmp_path, library, strength=0.5, width=40)
    assert expected(0.5) * 40 / 400 < 1.0 and pose_times(weak, 1.0, times, 40, 40) == [1.0] * 5
    builds = count_builds(monkeypatch)
    render_scene(weak, output=tmp_path / "one.exr", variant="llvm_ad_rgb")
    assert len(builds) == 1
    monkeypatch.setattr(loop, "POSE_PIXELS", 1e-12)
    _, weak5 = _sway_scene(tmp_path, library, strength=0.5, width=40)
    render_scene(weak5, output=tmp_path / "five.exr", variant="llvm_ad_rgb")
    assert len(builds) == 6
    a, b = read_exr(tmp_path / "one.exr")["rgb"], read_exr(tmp_path / "five.exr")["rgb"]
    assert np.abs(a.mean(axis=(0, 1)) / b.mean(axis=(0, 1)) - 1.0).max() < 0.01
    monkeypatch.setattr(loop, "POSE_PIXELS", 1.0)

    _, moving = _sway_scene(tmp_path, library, strength=2.0, camera_z1=24.0)  # 1 m a sub-frame, 27 px at 20 m
    assert pose_count(moving, 1.0, times, 400, 400) == 1
