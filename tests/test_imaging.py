"""forest.imaging: the view transform, the comp-ready EXR (Cryptomatte, camera, colour space) and the denoiser."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from forest.errors import ConfigError, ForestError
from forest.images import read_exr_channels, read_image
from forest.imaging import (
    CoverageAccumulator,
    TreeTable,
    camera_matrices,
    check_exposure,
    check_view,
    curves,
    denoise,
    extract_matte,
    forest_mattes,
    ocio_config,
    oidn_available,
    quantise,
    rank_coverage,
    to_display,
    write_comp_exr,
    write_display,
)
from forest.imaging import cryptomatte as cm
from forest.imaging.view import CONFIG_PATH, load_ocio_config

RNG = np.random.default_rng(20261123)


# ------------------------------------------------------------------ view transform


def test_the_view_transform_maps_mid_grey_as_documented():
    import colour

    grey = np.full((1, 1, 3), 0.18, dtype=np.float32)
    documented = {"agx": 0.5, "filmic": 0.5, "standard": float(colour.models.eotf_inverse_sRGB(0.18))}
    for view, code in documented.items():
        out = to_display(grey, view)
        assert out == pytest.approx(np.full((1, 1, 3), code), abs=2e-4), view
        assert np.all(np.abs(quantise(out).astype(int) - code * 255) <= 0.5 + 1e-3), view
    assert documented["standard"] == pytest.approx(0.4614, abs=1e-4)
    # +1 EV is the scene doubled
    for view in documented:
        assert to_display(grey, view, 1.0) == pytest.approx(to_display(2 * grey, view), abs=1e-5)


def test_standard_is_the_clipped_srgb_encoding_of_colour_science():
    import colour

    x = (RNG.random((64, 64, 3)) * 1.5).astype(np.float32)
    expected = colour.models.eotf_inverse_sRGB(np.clip(x, 0.0, 1.0))
    assert to_display(x, "standard") == pytest.approx(expected, abs=5e-5)


@pytest.mark.parametrize("view", ["agx", "filmic", "standard"])
def test_ocio_reproduces_the_documented_maths(view):
    x = (RNG.random((4096, 3)) * 3.0) ** 4 * 0.3  # 0 … ~24: shadows to past white
    assert to_display(x, view) == pytest.approx(curves.REFERENCE[view](x), abs=2e-4)


def test_tone_curves_are_monotonic_neutral_and_reach_white():
    ev = np.linspace(-12, 9, 400)
    greys = np.repeat((0.18 * np.exp2(ev))[:, None], 3, axis=1).astype(np.float32)
    for view in ("agx", "filmic", "standard"):
        out = to_display(greys, view)
        assert np.all(np.diff(out[:, 0]) >= -1e-6), view
        assert np.ptp(out, axis=1).max() < 1e-4, view  # grey stays grey
        assert out[-1] == pytest.approx([1.0, 1.0, 1.0], abs=1e-4), view
    # where white is reached, as documented
    assert to_display(np.full(3, 0.18 * 2**6.4), "agx")[0] < 0.999
    assert to_display(np.full(3, 0.18 * 2**3.9), "filmic")[0] < 0.999
    assert to_display(np.full(3, 0.18 * 2**4.2), "filmic")[0] == pytest.approx(1.0, abs=1e-4)


def test_stray_samples_never_poison_the_picture():
    bad = np.array([[np.nan, 0.18, 0.18], [np.inf, 0.18, 0.18], [-1.0, 0.18, 0.18], [1e30, 1e30, 1e30]], np.float32)
    for view in ("agx", "filmic", "standard"):
        out = to_display(bad, view)
        assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0
        assert out[0, 0] == out[2, 0] == pytest.approx(to_display(np.array([0.0, 0.18, 0.18]), view)[0], abs=1e-6)
        assert out[3] == pytest.approx([1.0, 1.0, 1.0], abs=1e-4)


def test_agx_takes_over_exposed_colour_to_white_instead_of_a_pure_primary():
    red = np.array([[1.0, 0.0, 0.0]], dtype=np.float32)
    assert to_display(red * 50.0, "standard")[0] == pytest.approx([1.0, 0.0, 0.0])
    bright = to_display(red * 50.0, "agx")[0]
    assert bright.min() > 0.6  # desaturated toward white
    mid = to_display(red * 0.18, "agx")[0]
    assert mid[0] > 0.45 and mid[1:].max() < 0.05  # a mid-tone red stays red


@pytest.mark.parametrize("look", sorted(curves.AGX_LOOKS))
def test_ocio_grades_each_look_as_the_asc_cdl_on_the_agx_log_encoding(look):
    x = (RNG.random((4096, 3)) * 3.0) ** 4 * 0.3
    assert to_display(x, "agx", look=look) == pytest.approx(curves.agx(x, look), abs=2.5e-4)
    # The CDL is the ASC's: clamp(x·S + O)^P, saturation about the Rec.709 luma (by hand for one value).
    s, o, p, sat = curves.AGX_LOOKS[look]
    v = np.array([0.7, 0.5, 0.2])
    sop = np.clip(v * s + o, 0.0, 1.0) ** p
    luma = 0.2126 * sop[0] + 0.7152 * sop[1] + 0.0722 * sop[2]
    assert curves.asc_cdl(v, s, o, p, sat) == pytest.approx(np.clip(luma + sat * (sop - luma), 0.0, 1.0), abs=1e-12)


def _chroma(rgb: np.ndarray) -> np.ndarray:
    return (rgb.max(axis=-1) - rgb.min(axis=-1)) / np.maximum(rgb.max(axis=-1), 1e-9)


def test_punchy_keeps_a_bright_blue_sky_blue_and_every_look_keeps_grey_grey():
    """A clear sky two stops over grey (linear (0.37, 0.52, 0.66), as measured in the demo's render) goes pale
    in the agx view; the punchy look gives it back its chroma and darkens the mid-tones; the contrast looks
    spread or squeeze a dark and a bright grey about the middle; no look tints a grey."""
    sky = np.array([[0.37, 0.52, 0.66]], np.float32)
    plain, punchy = to_display(sky, "agx")[0], to_display(sky, "agx", look="punchy")[0]
    std = to_display(sky, "standard")[0]
    assert _chroma(plain) < 0.7 * _chroma(std)  # the view's inset and shoulder take the sky's chroma …
    assert _chroma(punchy) > 1.5 * _chroma(plain)  # … and punchy gives much of it back
    grey = np.full((1, 3), 0.18, np.float32)
    assert to_display(grey, "agx", look="punchy")[0, 0] < to_display(grey, "agx")[0, 0] - 0.1
    ev = np.linspace(-8, 6, 60)
    greys = np.repeat((0.18 * np.exp2(ev))[:, None], 3, axis=1).astype(np.float32)
    spread = {}
    for look in ("none", *curves.AGX_LOOKS):
        out = to_display(greys, "agx", look=look)
        assert np.ptp(out, axis=1).max() < 1e-4, look  # grey stays grey
        assert np.all(np.diff(out[:, 0]) >= -1e-6), look
        spread[look] = float(out[30, 0] - out[20, 0])  # about −1 and +1 stop either side of grey
    assert spread["very_high_contrast"] > spread["high_contrast"] > spread["medium_high_contrast"] > spread["none"]
    assert spread["none"] > spread["medium_low_contrast"] > spread["low_contrast"] > spread["very_low_contrast"]


def test_a_look_needs_the_agx_view_and_a_known_name():
    from forest.config import parse_config
    from forest.imaging.view import check_look

    assert check_look("Punchy") == "punchy" and check_look("none", "filmic") == "none"
    with pytest.raises(ConfigError, match=r"render\.look: unknown look 'golden'"):
        check_look("golden")
    with pytest.raises(ConfigError, match=r"render\.look: look 'punchy' grades the agx view; the view is 'filmic'"):
        to_display(np.zeros((1, 3)), "filmic", look="punchy")
    base = '[terrain]\nflat = { size = 10.0 }\n[[species]]\nmodel = "broadleaf"\npercent = 100\n[render]\n'
    assert parse_config(base + 'look = "high_contrast"').render.look == "high_contrast"
    for bad, message in (('look = "golden"', "unknown look"), ('view = "filmic"\nlook = "punchy"', "grades the agx")):
        with pytest.raises(ConfigError, match=message) as e:
            parse_config(base + bad)
        assert e.value.field == "render.look"


def test_view_and_exposure_validation_name_the_field():
    assert check_view("AgX") == "agx"
    assert check_exposure(2) == 2.0
    for bad in ("aces2", "", None, 3):
        with pytest.raises(ConfigError) as e:
            check_view(bad, path="shot.toml")
        assert str(e.value).startswith("shot.toml: render.view: unknown view")
        assert "\n" not in str(e.value)
    for bad in (10.5, -11, float("nan"), float("inf"), True, "2"):
        with pytest.raises(ConfigError) as e:
            check_exposure(bad, path="shot.toml")
        assert str(e.value).startswith("shot.toml: render.exposure: ")
    with pytest.raises(ForestError, match=r"render\.view"):
        to_display(np.zeros((2, 2, 3)), "log")


def test_the_shipped_ocio_config_is_what_the_generator_writes(tmp_path):
    written = ocio_config.write_config(tmp_path)
    for path in written:
        if path.suffix == ".spi1d":
            assert path.read_bytes() == (CONFIG_PATH.parent / "luts" / path.name).read_bytes()
    import PyOpenColorIO as OCIO

    fresh = OCIO.Config.CreateFromFile(str(tmp_path / "config.ocio"))
    shipped = load_ocio_config()
    x = ((RNG.random((2000, 3)) * 3.0) ** 4 * 0.3).astype(np.float32)
    for view in ocio_config.VIEW_NAMES.values():
        outs = []
        for cfg in (fresh, shipped):
            a = x.copy()
            cfg.getProcessor(
                OCIO.DisplayViewTransform(src=ocio_config.SCENE_LINEAR, display=ocio_config.DISPLAY, view=view)
            ).getDefaultCPUProcessor().applyRGB(a)
            outs.append(a)
        assert np.array_equal(outs[0], outs[1]), view


def test_the_exr_colour_space_name_resolves_in_the_config():
    cfg = load_ocio_config()
    cfg.validate()
    assert cfg.getColorSpace(ocio_config.SCENE_LINEAR_INTEROP_ID).getName() == ocio_config.SCENE_LINEAR
    assert cfg.getColorSpace("scene_linear").getName() == ocio_config.SCENE_LINEAR
    assert set(cfg.getViews(ocio_config.DISPLAY)) >= set(ocio_config.VIEW_NAMES.values())
    # and OCIO's own studio config reads the EXR's colour-space name as the same space
    import PyOpenColorIO as OCIO

    studio = OCIO.Config.CreateFromFile("ocio://studio-config-latest")
    assert studio.getColorSpace(ocio_config.SCENE_LINEAR_INTEROP_ID).getName() == ocio_config.SCENE_LINEAR


@pytest.mark.parametrize("bits", [8, 16])
def test_display_png_holds_the_view_and_is_byte_identical(tmp_path, bits):
    x = (RNG.random((9, 13, 3)) * 4).astype(np.float32)
    a, b = tmp_path / "a.png", tmp_path / "b.png"
    write_display(a, x, view="filmic", exposure=1.0, bits=bits)
    write_display(b, x, view="filmic", exposure=1.0, bits=bits)
    assert a.read_bytes() == b.read_bytes()
    back = read_image(a)
    top = (1 << bits) - 1
    assert np.rint(back * top) == pytest.approx(quantise(to_display(x, "filmic", 1.0), bits).astype(float))


# ------------------------------------------------------------------ Cryptomatte


def test_names_hash_as_the_cryptomatte_specification_says():
    # The manifest example of the Cryptomatte specification (Psyop, v1.1.0+).
    ids = cm.name_ids(["bunny", "default", "bunny_porcelain_mat"])
    assert cm.id_hex(ids) == ["13851a76", "42c9679f", "b24b26d4"]
    # MurmurHash3_x86_32 reference values (SMHasher: "" → 0, seed 0).
    assert int(cm.murmurhash3_32("")) == 0


def test_murmurhash3_matches_the_mmh3_library():
    mmh3 = pytest.importorskip("mmh3")
    alphabet = list("abcxyz/_-.0123456789ÄéΩ木")
    names = ["".join(RNG.choice(alphabet, int(n))) for n in RNG.integers(0, 40, 3000)]
    ours = cm.murmurhash3_32(names)
    theirs = np.array([mmh3.hash(n, signed=False) for n in names], dtype=np.uint32)
    assert np.array_equal(ours, theirs)


def test_uint32_to_float32_keeps_every_id_a_normal_float():
    h = np.array([0x00000001, 0x007FFFFF, 0x7F800000, 0xFFFFFFFF, 0x3F800000, 0x80000000], dtype=np.uint32)
    f = cm.hash_to_float(h)
    assert np.isfinite(f).all()
    assert (np.abs(f) >= np.finfo(np.float32).tiny).all()
    changed = f.view(np.uint32) ^ h
    assert set(changed.tolist()) <= {0, 1 << 23}
    assert changed[4] == 0  # a normal exponent is left alone


def _brute_force_ranking(ids, w, ranks):
    out_ids = np.full(ids.shape[:2] + (ranks,), -1)
    out_cov = np.zeros(ids.shape[:2] + (ranks,))
    for i in range(ids.shape[0]):
        for j in range(ids.shape[1]):
            sums: dict[int, float] = {}
            for k in range(ids.shape[2]):
                if ids[i, j, k] != -1:
                    sums[int(ids[i, j, k])] = sums.get(int(ids[i, j, k]), 0.0) + float(w[i, j, k])
            ranked = sorted(sums.items(), key=lambda t: (-t[1], t[0]))[:ranks]
            for r, (obj, s) in enumerate(ranked):
                out_ids[i, j, r], out_cov[i, j, r] = obj, s / w[i, j].sum()
    return out_ids, out_cov


def test_the_ranking_filter_sums_weights_per_id_and_ranks_them():
    ids = RNG.integers(-3, 7, size=(5, 6, 24))
    w = RNG.random((5, 6, 24))
    ranking = rank_coverage(ids, w, ranks=6)
    exp_ids, exp_cov = _brute_force_ranking(ids, w, 6)
    assert np.array_equal(ranking.ids, exp_ids)
    assert ranking.coverage == pytest.approx(exp_cov, abs=1e-6)
    # pass by pass gives the same result while a pixel holds ≤ keep distinct ids
    acc = CoverageAccumulator(5, 6, keep=12)
    for k in range(0, 24, 5):
        acc.add(ids[..., k : k + 5], w[..., k : k + 5])
    again = acc.ranking(6)
    assert np.array_equal(again.ids, exp_ids)
    assert again.coverage == pytest.approx(exp_cov, abs=1e-6)


def _synthetic_frame(h=12, w=16, n=4):
    """Per-sample ids of discs (trees) in front of a terrain band under a sky, n×n samples per pixel."""
    trees = {  # tree id: (centre x, centre y, radius, depth) in pixels
        7: (4.3, 5.2, 3.1, 10.0),
        12: (7.9, 6.0, 2.6, 5.0),
        31: (12.2, 4.1, 2.2, 20.0),
    }
    off = (np.arange(n) + 0.5) / n
    sy, sx = np.meshgrid(off, off, indexing="ij")
    py, px = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    X = px[..., None] + sx.ravel()[None, None, :]
    Y = py[..., None] + sy.ravel()[None, None, :]
    ids = np.where(Y > 8.3, -2, -1).astype(np.int64)  # terrain below the horizon, sky above
    depth = np.where(ids == -2, 50.0, np.inf)
    for tid, (cx, cy, r, d) in trees.items():
        inside = (X - cx) ** 2 + (Y - cy) ** 2 < r * r
        front = inside & (d < depth)
        ids = np.where(front, tid, ids)
        depth = np.where(front, d, depth)
    return ids


def _table():
    return TreeTable(
        tree_ids=np.array([31, 7, 12, 99]),
        tree_species=np.array([1, 0, 0, 1]),
        species_names=["broadleaf", "conifer"],
        others={-2: "terrain"},
    )


def test_the_comp_exr_holds_the_new_channels_and_header_fields(tmp_path):
    ids = _synthetic_frame()
    h, w, s = ids.shape
    table = _table()
    trees, species = forest_mattes(ids, None, table)
    beauty = RNG.random((h, w, 3)).astype(np.float32) * 3
    alpha = (ids != -1).mean(axis=2)
    centre = ids[..., s // 2]
    cam = camera_matrices([1.0, 30.0, -80.0], [0.0, 10.0, 0.0], [0.0, 1.0, 0.0], 40.0, w, h, near=0.5, far=5000.0)
    path = tmp_path / "frame.exr"
    kwargs = {
        "alpha": alpha,
        "depth": RNG.random((h, w)).astype(np.float32) * 100,
        "tree_id": np.where(centre >= 0, centre, -1),
        "species": table.species_of(np.where(centre >= -1, centre, -1)),
        "species_names": table.species_names,
        "mattes": (trees, species),
        "camera": cam,
        "attributes": {"forest:frame": 1},
    }
    write_comp_exr(path, beauty, **kwargs)
    channels, header = read_exr_channels(path)

    expected = {"R", "G", "B", "A", "depth.Z", "id.Z", "species.Z"}
    for t in ("CryptoObject", "CryptoAsset"):
        expected |= {f"{t}{k:02d}.{c}" for k in range(3) for c in "RGBA"}
    assert set(channels) == expected
    assert np.array_equal(channels["R"], beauty[..., 0])
    assert channels["A"] == pytest.approx(alpha)
    # colour space: the standard chromaticities and an OCIO colour-space name
    assert header["chromaticities"] == pytest.approx((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290))
    assert header["oiio:ColorSpace"] == "lin_rec709_scene"
    assert load_ocio_config().getColorSpace(str(header["oiio:ColorSpace"])) is not None
    # camera matrices: stored transposed (Imath row vectors)
    assert header["worldToCamera"] == pytest.approx(cam.world_to_camera.T, abs=1e-5)
    assert header["worldToNDC"] == pytest.approx(cam.world_to_ndc.T, abs=1e-5)
    assert json.loads(str(header["forest:species_names"])) == ["broadleaf", "conifer"]
    # Cryptomatte metadata as the specification says
    for type_name, names in (("CryptoObject", ["broadleaf/7", "broadleaf/12", "conifer/31", "terrain"]),):
        key, manifest = cm.find_type(header, type_name)
        assert key == f"{int(cm.murmurhash3_32(type_name)):08x}"[:7]
        assert header[f"cryptomatte/{key}/hash"] == "MurmurHash3_32"
        assert header[f"cryptomatte/{key}/conversion"] == "uint32_to_float32"
        assert sorted(manifest) == sorted(names)
        assert all(manifest[n] == cm.id_hex(cm.name_ids([n]))[0] for n in names)

    # mattes extracted from the ranked layers recover the input coverage
    for tid, name in ((7, "broadleaf/7"), (12, "broadleaf/12"), (31, "conifer/31"), (-2, "terrain")):
        truth = (ids == tid).mean(axis=2)
        assert truth.max() > 0
        assert extract_matte(channels, "CryptoObject", [name]) == pytest.approx(truth, abs=1e-6)
    broadleaf = np.isin(ids, [7, 12]).mean(axis=2)
    assert extract_matte(channels, "CryptoAsset", ["broadleaf"]) == pytest.approx(broadleaf, abs=1e-6)
    assert extract_matte(channels, "CryptoObject", ["broadleaf/7", "broadleaf/12"]) == pytest.approx(
        broadleaf, abs=1e-6
    )
    # every object's coverage plus the sky's is the whole pixel
    total = sum(extract_matte(channels, "CryptoObject", [n]) for n in manifest)
    assert total + (ids == -1).mean(axis=2) == pytest.approx(np.ones((h, w)), abs=1e-6)

    again = tmp_path / "again.exr"
    write_comp_exr(again, beauty, **kwargs)
    assert again.read_bytes() == path.read_bytes()


def test_with_a_background_the_rgba_goes_over_the_sky_to_give_the_beauty(tmp_path):
    h, w = 6, 8
    alpha = RNG.random((h, w)).astype(np.float32)
    sky = np.array([0.4, 0.6, 1.2], dtype=np.float32) * np.ones((h, w, 3), np.float32)
    fg = RNG.random((h, w, 3)).astype(np.float32) * alpha[..., None]  # premultiplied foreground
    beauty = fg + sky * (1 - alpha[..., None])
    background = sky * (1 - alpha[..., None])  # the sky seen through the uncovered part of each pixel
    write_comp_exr(tmp_path / "f.exr", beauty, alpha=alpha, background=background)
    ch, header = read_exr_channels(tmp_path / "f.exr")
    rgb = np.stack([ch[c] for c in "RGB"], axis=-1)
    assert rgb == pytest.approx(fg, abs=1e-6)
    new_sky = np.array([1.0, 0.5, 0.2], dtype=np.float32)
    over = rgb + new_sky * (1 - ch["A"][..., None])
    assert over == pytest.approx(fg + new_sky * (1 - alpha[..., None]), abs=1e-6)
    restored = rgb + np.stack([ch[f"background.{c}"] for c in "RGB"], axis=-1)
    assert restored == pytest.approx(beauty, abs=1e-6)
    assert "premultiplied" in str(header["forest:layers"])


def test_tree_ids_that_a_float32_channel_would_round_are_refused(tmp_path):
    with pytest.raises(ValueError, match=r"id\.Z"):
        write_comp_exr(tmp_path / "f.exr", np.zeros((2, 2, 3)), tree_id=np.full((2, 2), 2**24 + 1))
    assert not (tmp_path / "f.exr").exists()


def test_camera_matrices_follow_openexr_conventions_against_mitsubas_camera():
    from forest.camera import look_at_matrix
    from forest.runtime import mitsuba

    mi = mitsuba("scalar_rgb")
    pos, target, up, fov, w, h = [12.0, 25.0, -40.0], [0.0, 5.0, 3.0], [0.0, 1.0, 0.0], 35.0, 320, 200
    sensor = mi.load_dict(
        {
            "type": "perspective",
            "fov": fov,
            "fov_axis": "x",
            "to_world": mi.ScalarTransform4f(look_at_matrix(pos, target, up)),
            "film": {"type": "hdrfilm", "width": w, "height": h},
        }
    )
    cam = camera_matrices(pos, target, up, fov, w, h, near=0.5, far=1000.0)
    for u, v in RNG.random((20, 2)):
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
        p = np.array(ray.o) + 20.0 * np.array(ray.d)
        ndc = cam.project(p[None])[0]
        assert ndc[:2] == pytest.approx([u, v], abs=1e-5)  # (0, 0) top-left, y down
        x, y, z, _ = cam.world_to_camera @ np.r_[p, 1.0]
        assert z > 0  # in front: +z
        assert np.sign(x) == np.sign(u - 0.5) and np.sign(y) == np.sign(0.5 - v)  # +x right, +y up
    assert cam.project(np.array([pos]) + 0.5 * (np.array([target]) - pos) / np.linalg.norm(np.subtract(target, pos)))[
        0, 2
    ] == pytest.approx(0.0, abs=1e-9)  # the near plane is NDC depth 0


# ------------------------------------------------------------------ denoiser


def test_denoise_without_oidn_returns_none(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    assert denoise(np.ones((4, 4, 3), np.float32)) is None


def test_denoise_rule_true_false_preview_and_auto(monkeypatch):
    """``[render] denoise``: true always, false never, --preview always; "auto" only at spp ≤ AUTO_MAX_SPP and only
    with pyoidn installed (silently off without it, the reason says so)."""
    import sys

    from forest.imaging.denoise import AUTO_MAX_SPP, denoise_rule

    assert denoise_rule(False, 1) == (False, "")
    assert denoise_rule(True, 10_000) == (True, "denoise = true")
    assert denoise_rule(False, 10_000, preview=True) == (True, "preview")
    assert denoise_rule("auto", AUTO_MAX_SPP + 1) == (False, f"auto: {AUTO_MAX_SPP + 1} spp > {AUTO_MAX_SPP}")
    if oidn_available():
        assert denoise_rule("auto", AUTO_MAX_SPP) == (True, f"auto: {AUTO_MAX_SPP} spp ≤ {AUTO_MAX_SPP}")
    monkeypatch.setitem(sys.modules, "pyoidn", None)
    assert denoise_rule("auto", 1) == (False, "auto: Open Image Denoise (pyoidn) not installed")


@pytest.mark.skipif(not oidn_available(), reason="Open Image Denoise (pyoidn) is not installed")
def test_albedo_and_normal_buffers_keep_texture_the_denoiser_would_smear():
    h, w = 96, 96
    yy, xx = np.mgrid[0:h, 0:w]
    albedo = np.where(((xx // 3) + (yy // 3)) % 2 == 0, 0.8, 0.1)[..., None] * np.array([0.6, 0.9, 0.4])
    normal = np.zeros((h, w, 3)) + np.array([0.0, 0.0, 1.0])
    light = 1.0 + 0.3 * np.sin(xx / 17.0)[..., None]
    clean = (albedo * light).astype(np.float32)
    noisy = (clean * RNG.gamma(2.0, 0.5, size=clean.shape)).astype(np.float32)  # mean-preserving noise
    plain = denoise(noisy)
    guided = denoise(noisy, albedo=albedo, normal=normal)
    assert plain is not None and guided is not None
    assert plain.shape == guided.shape == noisy.shape

    def err(img):
        return float(np.sqrt(np.mean((img - clean) ** 2)))

    assert err(guided) < 0.5 * err(plain)  # the 3-pixel checker survives only with the albedo
    assert err(guided) < 0.3 * err(noisy)
    # OIDN takes no normal without an albedo: such a normal is dropped, not an error
    assert np.array_equal(denoise(noisy, normal=normal), plain)


def test_image_files_carry_no_time_stamp(tmp_path):
    """Same pixels ⇒ same bytes: no writer may stamp the time (TIFF and OpenEXR do unless told)."""
    import OpenImageIO as oiio

    from forest.images import write_image

    img = np.random.default_rng(1).random((8, 8, 4)).astype(np.float32)
    for ext in (".tif", ".exr", ".png"):
        path = write_image(tmp_path / f"a{ext}", img)
        inp = oiio.ImageInput.open(str(path))
        stamp = inp.spec().getattribute("DateTime")
        inp.close()
        assert not stamp, (ext, stamp)


def test_srgb_decoding_gives_colour_sciences_values_to_the_bit():
    """forest's sRGB decoding is colour-science's eotf_sRGB (the same knee and float64 arithmetic): every 8- and
    16-bit code value, values around the knee, and out-of-range values clipped to [0, 1] decode to the same
    float32."""
    import colour

    from forest.images import SRGB_KNEE, srgb_to_linear

    knee = float(colour.models.eotf_inverse_sRGB(0.0031308))
    assert knee == SRGB_KNEE
    values = np.concatenate(
        [
            np.arange(256) / 255.0,
            np.arange(65536) / 65535.0,
            np.nextafter(knee, [-1.0, 2.0]),
            [knee, -0.5, 1.5, 0.0, 1.0],
            np.random.default_rng(3).random(10_000),
        ]
    )
    for a in (values, values.astype(np.float32), values.reshape(-1, 1)):
        want = np.asarray(colour.models.eotf_sRGB(np.clip(a, 0.0, 1.0)), dtype=np.float32)
        got = srgb_to_linear(a)
        assert got.dtype == np.float32 and got.shape == want.shape
        np.testing.assert_array_equal(got, want)
