"""[render] working_space = "acescg": the EXR holds ACEScg and says so; the ACES view is OCIO's ACES output transform."""

from __future__ import annotations

import numpy as np
import pytest

from forest.camera import CameraState
from forest.config import parse_config
from forest.errors import ConfigError
from forest.images import read_exr_channels
from forest.imaging.view import load_ocio_config, to_display
from forest.imaging.working_space import from_rec709, rgb_matrix
from forest.render.output import FrameImage, write_frame

RNG = np.random.default_rng(29)


def _ocio():
    import PyOpenColorIO as OCIO

    return OCIO


def test_the_matrix_is_the_one_ocio_uses() -> None:
    OCIO = _ocio()
    cfg = OCIO.Config.CreateRaw()
    proc = cfg.getProcessor(
        OCIO.BuiltinTransform(style="UTILITY - ACES-AP1_to_LINEAR-REC709_BFD", direction=OCIO.TRANSFORM_DIR_INVERSE)
    ).getDefaultCPUProcessor()
    rgb = np.eye(3, dtype=np.float32).copy()
    proc.applyRGB(rgb)
    assert pytest.approx(rgb_matrix("rec709", "acescg"), abs=2e-6) == rgb.T
    # White stays white (Bradford D65 → ACES white), and forest's config maps lin_ap1_scene back to Rec.709.
    assert rgb_matrix("rec709", "acescg").sum(axis=1) == pytest.approx(1.0, abs=1e-6)
    back = load_ocio_config().getProcessor("lin_ap1_scene", "lin_rec709_scene").getDefaultCPUProcessor()
    x = np.array([[0.2, 0.5, 0.9]], np.float32)
    y = from_rec709(x, "acescg").copy()
    back.applyRGB(y)
    assert y == pytest.approx(x, abs=1e-5)


def _frame(h: int = 6, w: int = 8) -> FrameImage:
    return FrameImage(
        rgb=(RNG.random((h, w, 3)) * 4).astype(np.float32),
        alpha=np.ones((h, w), np.float32),
        depth=np.full((h, w), 10.0, np.float32),
        id=np.zeros((h, w), np.float32),
        species=np.zeros((h, w), np.float32),
        camera=CameraState(np.array([0.0, 2.0, -10.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]), 40.0),
        levels=np.zeros(1),
        aovs={
            "albedo": RNG.random((h, w, 3)).astype(np.float32),
            "N": np.tile(np.array([0.0, 1.0, 0.0], np.float32), (h, w, 1)),
        },
    )


def test_acescg_exr_is_the_rec709_one_times_the_matrix(tmp_path) -> None:
    image = _frame()
    paths = {}
    for space in ("rec709", "acescg"):
        exr, png = tmp_path / f"{space}.exr", tmp_path / f"{space}.png"
        write_frame(
            exr, png, image, species_names=["a"], near=0.1, far=1000.0, view="aces", exposure=0.0,
            attributes={}, working_space=space,
        )  # fmt: skip
        paths[space] = (exr, png)
    rec, rec_header = read_exr_channels(paths["rec709"][0])
    ap1, header = read_exr_channels(paths["acescg"][0])
    m = rgb_matrix("rec709", "acescg")
    want = image.rgb.astype(np.float64) @ m.T
    got = np.stack([ap1[c] for c in "RGB"], axis=-1)
    assert got == pytest.approx(want, rel=1e-5, abs=1e-6)
    assert np.stack([rec[c] for c in "RGB"], axis=-1) == pytest.approx(image.rgb)
    albedo = np.stack([ap1[f"albedo.{c}"] for c in "RGB"], axis=-1)
    assert albedo == pytest.approx(image.aovs["albedo"].astype(np.float64) @ m.T, rel=1e-5, abs=1e-6)
    assert np.array_equal(ap1["N.Y"], rec["N.Y"]) and np.array_equal(ap1["depth.Z"], rec["depth.Z"])
    # The header says AP1 primaries with the ACES white point, and the Color Interop Forum ID.
    assert header["chromaticities"] == pytest.approx((0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767))
    assert header["oiio:ColorSpace"] == "lin_ap1_scene"
    assert rec_header["oiio:ColorSpace"] == "lin_rec709_scene"
    assert load_ocio_config().getColorSpace("lin_ap1_scene").getName() == "ACEScg"
    # The PNG is the same picture in both working spaces.
    assert paths["rec709"][1].read_bytes() == paths["acescg"][1].read_bytes()


def test_the_aces_view_is_ocios_aces_output_transform() -> None:
    OCIO = _ocio()
    ref = OCIO.Config.CreateFromFile("ocio://cg-config-v1.0.0_aces-v1.3_ocio-v2.1")
    proc = ref.getProcessor(
        OCIO.DisplayViewTransform(src="Linear Rec.709 (sRGB)", display="sRGB - Display", view="ACES 1.0 - SDR Video")
    ).getDefaultCPUProcessor()
    grey = np.array([0.01, 0.05, 0.18, 0.5, 1.0, 2.0, 4.0, 16.0, 100.0], np.float32)
    x = np.concatenate([np.repeat(grey[:, None], 3, axis=1), RNG.random((64, 3)).astype(np.float32) * 3])
    ours = to_display(x, "aces")
    theirs = x.copy()
    proc.applyRGB(theirs)
    assert ours == pytest.approx(np.clip(theirs, 0.0, 1.0), abs=1e-5)
    g = ours[: len(grey), 1]
    assert g[2] == pytest.approx(0.356, abs=0.002)  # 18 % grey: ACES 1.x SDR video puts it near code 0.36
    assert np.all(np.diff(g[:-1]) > 0)  # monotonic up the grey ramp ...
    assert 0.75 < g[4] < 0.85 and g[6] < 0.97 and g[7] > 0.99  # ... highlights roll off, not clip, toward white


def test_working_space_in_the_config() -> None:
    base = '[terrain]\nflat = {}\n[[species]]\nmodel = "broadleaf"\npercent = 100\n'
    assert parse_config(base).render.working_space == "rec709"
    assert parse_config(base + '[render]\nworking_space = "acescg"\nview = "aces"\n').render.working_space == "acescg"
    with pytest.raises(ConfigError, match="working_space"):
        parse_config(base + '[render]\nworking_space = "aces2065"\n')
