"""forest_path's tables live in memory drjit owns: the kernel does not depend on numpy's allocator.

drjit maps a numpy buffer without copying in ``llvm_ad_rgb`` and compiles a
4-wide gather from it as one packet load only when the buffer is 64-byte
aligned, so the same scene compiled to different kernels (and missed drjit's
kernel cache) depending on where numpy placed its tables.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from test_forest_path import Material, PathCamera, PathScene, SunLight, Surface, card_texture, look, quad, surfaces_only

from forest.render.path.arrays import opaque, owned

VARIANT = "llvm_ad_rgb"


@pytest.fixture(autouse=True)
def variant():
    mi.set_variant(VARIANT)


def aligned_views(n: int) -> list[np.ndarray]:
    """The same n floats at a 64-byte aligned address and 4 bytes past one."""
    views = []
    for off in (0, 4):
        buf = np.zeros(n * 4 + 256, np.uint8)
        start = (-buf.ctypes.data) % 64 + off
        v = buf[start : start + n * 4].view(np.float32)
        v[:] = np.arange(n, dtype=np.float32)
        views.append(v)
    return views


def gather_kernel(src) -> tuple[str, np.ndarray]:
    """Hash of the kernel that gathers Vector4f rows from ``src``, and the rows it read."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # clear
        v = dr.gather(mi.Vector4f, src, dr.arange(mi.UInt32, 8) % 3)
        dr.eval(v)
        (k,) = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return k["hash"], np.asarray(v).T


def test_plain_numpy_arrays_compile_by_address():
    """Why ``owned`` exists: the same values at two addresses give two kernels (drjit 1.5)."""
    a, b = aligned_views(12)
    assert gather_kernel(mi.Float(a))[0] != gather_kernel(mi.Float(b))[0]


def test_owned_arrays_compile_one_kernel_and_keep_their_values():
    a, b = aligned_views(12)
    (ha, va), (hb, vb) = gather_kernel(owned(mi.Float, a)), gather_kernel(owned(mi.Float, b))
    assert ha == hb
    expected = np.arange(12, dtype=np.float32).reshape(3, 4)[np.arange(8) % 3]
    np.testing.assert_array_equal(va, expected)
    np.testing.assert_array_equal(vb, expected)


def test_owned_arrays_do_not_alias_numpy():
    a = np.arange(8, dtype=np.float32)
    plain, mine = mi.Float(a), owned(mi.Float, a)
    a[0] = 100.0
    assert float(plain[0]) == 100.0  # drjit mapped the buffer (why the copy matters)
    assert float(mine[0]) == 0.0


def test_owned_keeps_types_and_tensor_shapes():
    img = np.arange(2 * 3 * 4, dtype=np.float32).reshape(2, 3, 4)
    t = owned(mi.TensorXf, img)
    assert isinstance(t, mi.TensorXf) and tuple(t.shape) == (2, 3, 4)
    np.testing.assert_array_equal(np.asarray(t), img)
    u = owned(mi.UInt32, np.array([3, 1, 2], np.uint32))
    assert isinstance(u, mi.UInt32) and np.asarray(u).tolist() == [3, 1, 2]
    i = owned(mi.Int32, np.array([-1, 5], np.int32))
    assert isinstance(i, mi.Int32) and np.asarray(i).tolist() == [-1, 5]


def test_a_scene_built_twice_reuses_its_kernels(tmp_path):
    """A textured cut-out card over a ground, built and rendered twice in one process: the second
    render compiles nothing (every kernel a cache hit), so drjit's disk cache serves later runs too."""
    camera = PathCamera(look([0.0, 30.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 20.0, 8, 8)
    sun = SunLight((0.0, 1.0, 0.0), (1.0, 1.0, 1.0))
    ground = Surface(quad(0.0, 20.0), Material("surface", (0.5, 0.5, 0.5)))
    card = Surface(
        quad(5.0, 5.0), Material("leaf", (0.8, 0.8, 0.8), texture=card_texture(tmp_path / "c.png", 0.5, 1.0))
    )
    PathScene(surfaces_only([ground, card], camera, sun=sun, spp=2), VARIANT).render()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        for _ in range(3):  # fresh numpy tables at fresh addresses each time
            PathScene(surfaces_only([ground, card], camera, sun=sun, spp=2), VARIANT).render()
        misses = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT and not k.get("cache_hit")]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert misses == []


def test_new_light_values_compile_no_new_kernel(tmp_path):
    """Look-dev sets a scene's lights (and tints, haze) to new values at every step: held as kernel parameters
    (:func:`forest.render.path.arrays.opaque`), every value renders with the same kernel and shows; as literals
    (``mi.Color3f(r, g, b)``, what forest did) each value was a kernel of its own, compiled anew."""
    camera = PathCamera(look([0.0, 30.0, 0.0], [0.0, 0.0, 0.0], (0.0, 0.0, 1.0)), 20.0, 8, 8)
    sun = SunLight((0.0, 1.0, 0.0), (1.0, 1.0, 1.0))
    ground = Surface(quad(0.0, 20.0), Material("surface", (0.5, 0.5, 0.5)))
    scene = PathScene(surfaces_only([ground], camera, sun=sun, spp=2), VARIANT)
    before = float(np.mean(scene.render().rgb))
    (param,) = [light.param for light in scene.lights]

    def render_with(value) -> tuple[set[str], np.ndarray]:
        scene.params[param] = value
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        try:
            dr.kernel_history()
            rgb = np.asarray(scene.render().rgb).reshape(-1, 3).mean(0)
            jit = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT]
        finally:
            dr.set_flag(dr.JitFlag.KernelHistory, False)
        return {k["hash"] for k in jit}, rgb

    k1, rgb1 = render_with(opaque(mi.Color3f, 2.0, 2.0, 2.0))
    k2, rgb2 = render_with(opaque(mi.Color3f, 0.5, 0.25, 1.0))
    assert k1 == k2
    np.testing.assert_allclose(rgb1, 2.0 * before, rtol=1e-3)
    np.testing.assert_allclose(rgb2, [0.5 * before, 0.25 * before, before], rtol=1e-3)
    l1, _ = render_with(mi.Color3f(1.5, 1.5, 1.5))  # why: a literal is part of the kernel's code
    l2, _ = render_with(mi.Color3f(2.5, 2.5, 2.5))
    assert l1 != l2
