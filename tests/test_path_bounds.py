"""forest_path is bounded and resolves hits the same way on every back-end (no GPU needed).

* Every loop of the path tracer has a hard cap: the per-lane segment counter of each example
  scene stays within :func:`forest.render.path.integrator.segment_cap`, the bound the loop's
  structure implies (its guard, one past it, is never reached).
* OptiX (``cuda_ad_rgb``) reports an instanced hit differently from Embree (``llvm_ad_rgb``):
  the part mesh's registry id in ``pi.shape`` and 0 in ``pi.shape_index``, where Embree gives a
  null ``pi.shape`` and the part's index in ``pi.shape_index``.  Hits traced here by Embree and
  rewritten the OptiX way resolve to the same tree, part and triangle.  (Before this was handled,
  every instanced hit on the GPU resolved to the first part of its tree.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from forest.config import load_config
from forest.render.path import PathScene
from forest.render.path.from_scene import path_inputs
from forest.render.path.geometry import resolve
from forest.render.path.integrator import MAX_SKIPS, segment_cap
from forest.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))
VARIANT = "llvm_ad_rgb"


def test_segment_cap_counts_the_chains_of_a_path():
    # max_depth 1: one camera chain (MAX_SKIPS texels passed, then a stop); each further depth adds a shadow
    # chain and a bounce chain.
    assert segment_cap(1) == MAX_SKIPS + 1
    assert segment_cap(3) - segment_cap(2) == 2 * MAX_SKIPS + 1
    # Light shafts: one more shadow chain per path (the haze's, from one point of the camera ray).
    assert segment_cap(3, shafts=True) - segment_cap(3) == MAX_SKIPS


@pytest.mark.parametrize("name", EXAMPLES)
def test_segment_counts_stay_within_their_cap_on_every_example(name):
    scene = load_scene(load_config(ROOT / "configs" / f"{name}.toml"))
    inputs = path_inputs(scene, width=40, height=24, spp=2)
    path = PathScene(inputs, VARIANT)
    counts = np.concatenate([p.segments.ravel() for p in path.passes(aux=True)])
    assert counts.size == 40 * 24 * 2
    assert counts.min() >= 1
    shafts = inputs.haze is not None and inputs.haze.shafts
    assert counts.max() <= segment_cap(inputs.max_depth, shafts)
    # Paths do bounce and pass cut-outs here: the counter counts, it is not stuck at its first value.
    assert counts.max() > counts.min()


def test_optix_style_instanced_hits_resolve_like_embrees():
    import drjit as dr

    scene = load_scene(load_config(ROOT / "configs" / "demo.toml"))
    inputs = path_inputs(scene, width=64, height=36, spp=1)
    inputs.flatten_triangles = 0  # every tree instanced
    path = PathScene(inputs, VARIANT)
    mi, trav = path.mi, path.traversal
    _, ray, _ = path._camera_rays(inputs.camera, 1, 7)
    pi = trav.scene.ray_intersect_preliminary(ray)
    embree = resolve(mi, trav, path._parts, pi, mi.Bool(True))
    inst = np.asarray(dr.reinterpret_array(mi.UInt32, pi.instance))
    part = np.asarray(embree.part)
    instanced = np.asarray(pi.is_valid()) & (inst != 0)
    assert instanced.sum() > 500
    # More than one part per tree is hit (trunk, branches, leaves): the case OptiX's shape_index = 0 broke.
    local = np.asarray(pi.shape_index)[instanced]
    assert len(np.unique(local)) > 1
    # Rewrite the hits as OptiX reports them.
    shape = np.zeros_like(inst)
    shape[instanced] = [trav.part_mesh_reg[int(p)] for p in part[instanced]]
    top = ~instanced & np.asarray(pi.is_valid())
    shape[top] = np.asarray(dr.reinterpret_array(mi.UInt32, pi.shape))[top]
    optix = mi.PreliminaryIntersection3f(pi)
    optix.shape = dr.reinterpret_array(mi.ShapePtr, mi.UInt32(shape))
    optix.shape_index = mi.UInt32(np.zeros_like(inst))
    got = resolve(mi, trav, path._parts, optix, mi.Bool(True))
    np.testing.assert_array_equal(np.asarray(got.valid), np.asarray(embree.valid), "valid")
    hit = np.asarray(embree.valid).astype(
        bool
    )  # a ray that leaves the scene (the sky) carries no row, part or triangle
    for field in ("row", "part", "tri"):
        np.testing.assert_array_equal(
            np.asarray(getattr(got, field))[hit], np.asarray(getattr(embree, field))[hit], field
        )
