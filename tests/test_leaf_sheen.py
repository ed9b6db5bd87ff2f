"""The leaf cuticle's rough specular lobe (issue 27): a mirror peak, energy kept, sampling, opt-in bytes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_forest_path import VARIANT, look, quad, surfaces_only

from forest.errors import ForestError
from forest.render.path import Material, PathCamera, PathScene, SkyLight, SunLight, Surface
from forest.render.path.materials import CUTICLE_F0, Shading, bsdf_eval, bsdf_sample, leaf_sheen, sheen_albedo_table


@pytest.fixture(scope="module")
def mi():
    from forest.runtime import mitsuba

    return mitsuba(VARIANT)


def leaf_shading(mi, n: int, *, sheen: float, alpha: float, albedo=(1.0, 1.0, 1.0), tau: float = 0.4) -> Shading:
    a = np.asarray(albedo, np.float32)
    R, T = a * (1 - tau), a * tau
    p_r = R.sum() / (R.sum() + T.sum())
    return Shading(
        reflect=mi.Color3f(*(float(x) for x in R)),
        transmit=mi.Color3f(*(float(x) for x in T)),
        p_reflect=mi.Float(float(p_r)),
        sheen=mi.Float(sheen),
        alpha=mi.Float(alpha),
        material=mi.UInt32(0) if n == 1 else mi.UInt32(np.zeros(n, np.uint32)),
        albedo_table=mi.Float(sheen_albedo_table(alpha)),
    )


def direction(theta_deg: float, phi_deg: float = 0.0) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def eval_np(mi, sh, wi, wo):
    n = len(wo)
    N = mi.Vector3f(np.zeros(n, np.float32), np.zeros(n, np.float32), np.ones(n, np.float32))
    WO = mi.Vector3f(*(np.asarray(wo[:, k], np.float32) for k in range(3)))
    WI = mi.Vector3f(*(np.full(n, wi[k], np.float32) for k in range(3)))
    value, pdf = bsdf_eval(sh, N, WO, WI)
    return np.array(value).T if np.ndim(np.array(value)) == 2 else np.array(value), np.array(pdf)


def ggx_spec(wi, wo, alpha, s=1.0):
    """f·μo of the specular lobe, written out independently (Walter et al. 2007; Heitz 2014)."""
    h = (wi + wo) / np.linalg.norm(wi + wo)
    d = alpha**2 / (np.pi * (h[2] ** 2 * (alpha**2 - 1) + 1) ** 2)

    def lam(w):
        return 0.5 * (np.sqrt(1 + alpha**2 * (1 - w[2] ** 2) / w[2] ** 2) - 1)

    f = CUTICLE_F0 + (1 - CUTICLE_F0) * (1 - wi @ h) ** 5
    return s * f * d / (1 + lam(wi) + lam(wo)) / (4 * wi[2])


def test_a_leaf_seen_from_the_mirror_direction_shows_a_specular_peak(mi):
    """bsdf_eval at the mirror direction against 35° off it: the GGX peak over the Lambertian floor."""
    alpha, s = 0.3, 1.0
    albedo = (0.1, 0.18, 0.03)
    sh = leaf_shading(mi, 1, sheen=s, alpha=alpha, albedo=albedo)
    wi = direction(70.0, 180.0)
    mirror, off = direction(70.0, 0.0), direction(35.0, 0.0)
    value, _ = eval_np(mi, sh, wi, np.stack([mirror, off]))
    E = float(np.interp(wi[2], np.linspace(0, 1, 33), sheen_albedo_table(alpha)))
    R = np.asarray(albedo) * 0.6
    for k, wo in enumerate((mirror, off)):
        expected = ggx_spec(wi, wo, alpha, s) + (1 - s * E) * R / np.pi * wo[2]
        np.testing.assert_allclose(value[k], expected, rtol=2e-3)
    # White (unchromatic) and strongest at the mirror direction: here more than 3× the off-mirror green.
    assert value[0][1] / value[1][1] > 3.0
    spec = value[0] - (1 - s * E) * R / np.pi * mirror[2]
    np.testing.assert_allclose(spec, spec[0], rtol=1e-4)
    # Without the lobe the same directions are Lambertian: brighter off the mirror (larger cos θo).
    flat = leaf_shading(mi, 1, sheen=0.0, alpha=alpha, albedo=albedo)
    v0, _ = eval_np(mi, flat, wi, np.stack([mirror, off]))
    assert v0[0][1] < v0[1][1]


@pytest.mark.parametrize("alpha", [0.2, 0.35, 0.5, 1.0])
def test_directional_albedo_is_at_most_one(mi, alpha):
    """∫ f·|cos θo| dωo over the sphere (midpoint rule in cos θo, φ), white leaf, s = 1: ≤ 1 and ≈ 1 (R + T = 1,
    so what the cuticle reflects is exactly what the diffuse lobes lose); a green leaf's is s·E + (1 − s·E)·a."""
    k = 640
    mu = (np.arange(k) + 0.5) / k
    phi = (np.arange(k) + 0.5) / k * 2 * np.pi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    st = np.sqrt(1 - M**2)
    up = np.stack([st * np.cos(P), st * np.sin(P), M], axis=-1).reshape(-1, 3)
    dirs = np.concatenate([up, up * [1, 1, -1]])
    dw = 2 * np.pi / (k * k)
    for theta in (0.0, 30.0, 60.0, 80.0, 89.0):
        wi = direction(theta, 90.0)
        sh = leaf_shading(mi, len(dirs), sheen=1.0, alpha=alpha)
        value, _ = eval_np(mi, sh, wi, dirs)
        total = value.sum(axis=0) * dw
        assert np.all(total <= 1.0 + 3e-3), (theta, total)
        assert total[1] == pytest.approx(1.0, abs=1e-2)
        green = leaf_shading(mi, len(dirs), sheen=1.0, alpha=alpha, albedo=(0.1, 0.18, 0.03))
        gv, _ = eval_np(mi, green, wi, dirs)
        E = float(np.interp(wi[2], np.linspace(0, 1, 33), sheen_albedo_table(alpha)))
        np.testing.assert_allclose(gv.sum(axis=0) * dw, E + (1 - E) * np.array([0.1, 0.18, 0.03]), atol=1e-2)


def test_sampling_agrees_with_evaluation(mi):
    """E[f·|cos|/pdf] over bsdf_sample's directions equals the albedo by quadrature, and each sample's pdf
    is bsdf_eval's (the mixture density MIS weighs against light sampling)."""
    import drjit as dr

    alpha, n = 0.35, 1 << 16
    wi = direction(65.0, 20.0)
    sh = leaf_shading(mi, n, sheen=1.0, alpha=alpha, albedo=(0.3, 0.5, 0.2))
    rng = np.random.default_rng(3)
    u = rng.random((n, 3)).astype(np.float32)
    frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    WI = mi.Vector3f(*(float(x) for x in wi))
    wo, weight, pdf = bsdf_sample(mi, sh, frame, mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]), WI)
    dr.eval(wo, weight, pdf)
    _, pdf_e = bsdf_eval(sh, frame.n, wo, WI)
    ok = np.array(pdf) > 0
    np.testing.assert_allclose(np.array(pdf)[ok], np.array(pdf_e)[ok], rtol=1e-3, atol=1e-6)
    est = np.array(weight).mean(axis=1)
    k = 512
    mu = (np.arange(k) + 0.5) / k
    M, P = np.meshgrid(mu, (np.arange(k) + 0.5) / k * 2 * np.pi, indexing="ij")
    st = np.sqrt(1 - M**2)
    up = np.stack([st * np.cos(P), st * np.sin(P), M], axis=-1).reshape(-1, 3)
    dirs = np.concatenate([up, up * [1, 1, -1]])
    qv, _ = eval_np(mi, leaf_shading(mi, len(dirs), sheen=1.0, alpha=alpha, albedo=(0.3, 0.5, 0.2)), wi, dirs)
    np.testing.assert_allclose(est, qv.sum(axis=0) * 2 * np.pi / (k * k), rtol=0.01)


def test_render_at_the_mirror_direction(tmp_path):
    """A horizontal leaf, a sun 60° from the zenith, a narrow camera at the mirror direction: the render is
    E·(spec + (1 − s·E(μ))·R/π·μ)-bright, as the analytic lobe says."""
    alpha, s, albedo, tau = 0.35, 1.0, (0.1, 0.18, 0.03), 0.4
    ls = direction(60.0, 0.0)
    sun = SunLight((float(ls[0]), float(ls[2]), float(ls[1])), (2.0, 2.0, 2.0))  # z-up direction → y-up world
    view = direction(60.0, 180.0)
    eye = np.array([view[0], view[2], view[1]]) * 10.0
    camera = PathCamera(look(eye.tolist(), [0.0, 0.0, 0.0]), 2.0, 4, 4)
    out = {}
    for sheen in (0.0, s):
        leaf = Surface(quad(0.0, 5.0), Material("leaf", albedo, translucency=tau, sheen=sheen, roughness=alpha))
        out[sheen] = PathScene(surfaces_only([leaf], camera, sun=sun, spp=4), VARIANT).render().rgb.reshape(-1, 3)
    mu = float(np.cos(np.radians(60.0)))
    E = float(np.interp(mu, np.linspace(0, 1, 33), sheen_albedo_table(alpha)))
    R = np.asarray(albedo) * (1 - tau)
    expected = 2.0 * (ggx_spec(view, ls, alpha, s) + (1 - s * E) * R / np.pi * mu)
    np.testing.assert_allclose(out[s].mean(axis=0), expected, rtol=0.02)
    np.testing.assert_allclose(out[0.0].mean(axis=0), 2.0 * R / np.pi * mu, rtol=1e-3)
    assert out[s].mean() > 1.5 * out[0.0].mean()


def test_white_furnace_with_sheen():
    """Stacked white leaves with a cuticle lobe in a uniform sky, many bounces: every leaf shows the sky's
    radiance (energy kept through the mixture sampling and MIS)."""
    camera = PathCamera(look([0.0, 10.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 10.0, 6, 6)
    m = Material("leaf", (1.0, 1.0, 1.0), translucency=0.5, sheen=1.0, roughness=0.4)
    leaves = [Surface(quad(y, 20.0), m) for y in (0.0, 1.0)]
    sky = SkyLight("constant", radiance=(0.5, 0.5, 0.5))
    deep = PathScene(surfaces_only(leaves, camera, sky=sky, spp=256, max_depth=64), VARIANT).render()
    np.testing.assert_allclose(deep.rgb.mean(), 0.5, rtol=0.02)


def test_sheen_zero_is_byte_identical():
    """s = 0 on every leaf traces the code without the lobe: the same bytes as a material without the field."""
    sun = SunLight((0.3, 0.8, 0.2), (2.0, 2.0, 2.0))
    camera = PathCamera(look([3.0, 4.0, 5.0], [0.0, 0.0, 0.0]), 40.0, 8, 8)
    imgs = []
    for m in (
        Material("leaf", (0.1, 0.2, 0.05), translucency=0.4),
        Material("leaf", (0.1, 0.2, 0.05), translucency=0.4, sheen=0.0, roughness=0.5),
    ):
        scene = PathScene(surfaces_only([Surface(quad(0.0, 2.0), m)], camera, sun=sun, spp=4, max_depth=3), VARIANT)
        imgs.append(scene.render().rgb)
    assert imgs[0].tobytes() == imgs[1].tobytes()


@pytest.mark.parametrize(
    ("sheen", "rough", "words"),
    [(1.5, 0.3, "leaf sheen must be in [0, 1], got 1.5"), (-0.1, 0.3, "sheen"), (0.5, 0.0, "leaf roughness"),
     (0.5, 2.0, "leaf roughness"), (float("nan"), 0.3, "sheen")],
)  # fmt: skip
def test_bad_values_are_refused_on_one_line(sheen, rough, words):
    with pytest.raises(ForestError) as e:
        leaf_sheen(Material("leaf", (0.1, 0.2, 0.1), sheen=sheen, roughness=rough))
    assert words in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(("key", "value"), [("leaf_sheen", 1.5), ("leaf_sheen", True), ("leaf_roughness", 0.0)])
def test_bad_recipe_values_name_the_file_and_field(key, value):
    """A preset's sheen or roughness out of range: ``file: tree.key: …`` on one line (the CLI exits 2)."""
    import tomllib

    from forest.errors import ConfigError
    from forest.library.generator import validate_recipe

    root = Path(__file__).resolve().parents[1]
    recipe = tomllib.loads((root / "library" / "presets" / "conifer.toml").read_text())
    assert recipe["tree"]["leaf_sheen"] == 1.0 and recipe["tree"]["leaf_roughness"] == 0.5
    recipe["tree"][key] = value
    with pytest.raises(ConfigError) as e:
        validate_recipe(recipe, "conifer.toml")
    assert str(e.value).startswith(f"conifer.toml: tree.{key}: must be a number in") and "\n" not in str(e.value)


def test_scalar_rgb_warns_once_that_it_keeps_lambertian_leaves(monkeypatch):
    import forest.render.instancing as instancing
    from forest.errors import ForestWarning

    monkeypatch.setattr(instancing, "_SHEEN_WARNED", False)
    with pytest.warns(ForestWarning, match="without their cuticle sheen") as record:
        instancing._warn_sheen_once()
        instancing._warn_sheen_once()
    assert len(record) == 1
