"""Row-wise work split over threads (forest.parallel): the same bits as one call, and a scatter unchanged by it."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import write_scene

import forest.parallel as parallel
from forest.config import load_config
from forest.parallel import rowwise
from forest.scatter import scatter


def _fn(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return np.cbrt(a) * b[:, None], np.sin(b) ** 3


@pytest.mark.parametrize("n_workers", [1, 2, 3, 8])
def test_rowwise_gives_the_bits_of_one_call(monkeypatch, n_workers):
    monkeypatch.setattr(parallel, "workers", lambda: n_workers)
    parallel._pool.cache_clear()
    rng = np.random.default_rng(4)
    a, b = rng.random((10_007, 3)), rng.random(10_007)
    one = _fn(a, b)
    split = rowwise(_fn, a, b, min_rows=100)
    assert all(np.array_equal(x, y) for x, y in zip(one, split))
    single = rowwise(lambda x: x * 2.0, b, min_rows=100)
    assert np.array_equal(single, b * 2.0)
    # Under min_rows: one call, the function sees the whole arrays.
    seen = []
    rowwise(lambda x: seen.append(len(x)) or x, b, min_rows=20_000)
    assert seen == [10_007]
    # Nested: a block that splits again runs its part in place (no wait on its own pool).
    nested = rowwise(lambda x: rowwise(lambda y: y + 1.0, x, min_rows=10), b, min_rows=100)
    assert np.array_equal(nested, b + 1.0)
    parallel._pool.cache_clear()


def test_scatter_is_the_same_on_one_core_and_on_several(tmp_path, monkeypatch):
    """Terrain sampling, normals, map lookups, stands and tints split over threads: the same InstanceSet bytes."""
    cfg = write_scene(
        tmp_path,
        """
        seed = 9
        [terrain]
        procedural = { size = 800.0, height = 60.0, resolution = 64 }
        [scatter]
        count = 60000
        [[species]]
        model = "broadleaf"
        percent = 60
        [[species]]
        model = "conifer"
        percent = 40
        """,
    )
    monkeypatch.setattr(parallel, "MIN_ROWS", 5_000)
    out = []
    for n in (1, 3):
        monkeypatch.setattr(parallel, "workers", lambda n=n: n)
        parallel._pool.cache_clear()
        inst, _ = scatter(load_config(cfg))
        inst.save(tmp_path / f"w{n}.npz")
        out.append((tmp_path / f"w{n}.npz").read_bytes())
    parallel._pool.cache_clear()
    assert len(inst) > 30_000 and out[0] == out[1]


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="needs fork")
def test_a_forked_child_makes_its_own_pool(monkeypatch):
    """A child forked after the pool started splits work again (its parent's threads are not in it)."""
    import os

    monkeypatch.setattr(parallel, "workers", lambda: 2)
    parallel._pool.cache_clear()
    b = np.arange(1000.0)
    assert np.array_equal(rowwise(lambda x: x * 3.0, b, min_rows=100), b * 3.0)  # the parent's pool exists now
    pid = os.fork()
    if pid == 0:  # the child: exit 0 only if the split work comes back
        ok = np.array_equal(rowwise(lambda x: x * 3.0, b, min_rows=100), b * 3.0)
        os._exit(0 if ok else 1)
    _, status = os.waitpid(pid, 0)
    parallel._pool.cache_clear()
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0


@pytest.mark.parametrize("n_workers", [2, 3, 8])
def test_coverage_counted_in_blocks_of_pixels_equals_one_block(monkeypatch, n_workers):
    """A frame's Cryptomatte coverage counted on pixel blocks in threads (forest.parallel.blockwise) holds the same
    slots and counts as one block: passes where a third of the pixels meet two to five ids, some of them new to
    the pixel in later passes, and sky samples (NONE) among them."""
    from forest.imaging.cryptomatte import NONE
    from forest.render.coverage import SampleCoverage

    rng = np.random.default_rng(11)
    h, w, spp = 37, 53, 4
    base = rng.integers(0, 40, h * w)
    passes = []
    for _ in range(5):
        ids = np.repeat(base[:, None], spp, axis=1)
        mixed = rng.random(ids.shape) < 0.3
        ids[mixed] = rng.integers(0, 5, int(mixed.sum())) + 100 * rng.integers(0, 2, int(mixed.sum()))
        ids[rng.random(ids.shape) < 0.1] = NONE
        passes.append(ids)

    def count(workers: int) -> SampleCoverage:
        monkeypatch.setattr(parallel, "workers", lambda: workers)
        monkeypatch.setattr(parallel, "MIN_ROWS", 64)
        parallel._pool.cache_clear()
        cov = SampleCoverage(h, w)
        for ids in passes:
            cov.add(ids)
        return cov

    one, split = count(1), count(n_workers)
    parallel._pool.cache_clear()
    assert np.array_equal(one.ids, split.ids) and np.array_equal(one.count, split.count)
    assert np.array_equal(one.total, split.total)
    assert (one.count[:, 1] > 0).sum() > h * w // 5  # the case is not trivial: many pixels hold two or more slots
    np.testing.assert_array_equal(one.count.sum(axis=1) + (np.stack(passes) == NONE).sum(axis=(0, 2)), one.total)


def test_display_transform_in_blocks_equals_one_call(monkeypatch):
    """The OCIO display transform applied on pixel blocks in threads gives the same code values as one call."""
    from forest.imaging.view import to_display

    rgb = np.random.default_rng(5).uniform(0.0, 6.0, (300, 400, 3)).astype(np.float32)
    monkeypatch.setattr(parallel, "MIN_ROWS", 1000)
    monkeypatch.setattr(parallel, "workers", lambda: 1)
    one = to_display(rgb, "agx", 0.5, "punchy")
    monkeypatch.setattr(parallel, "workers", lambda: 4)
    parallel._pool.cache_clear()
    split = to_display(rgb, "agx", 0.5, "punchy")
    parallel._pool.cache_clear()
    assert np.array_equal(one, split) and one.std() > 0.05
