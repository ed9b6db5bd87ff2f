"""The colour map a fit writes: the artist's painted map times a fitted correction field.

An aligned fit does not replace the painted map (256×256, say) by a coarse
grid: it fits an n×n field c of ln-corrections (``--grid``; ``auto`` picks n from
the pixels the reference gives each cell, :func:`.match.auto_grid`) and writes

    M'(x) = M(x) · exp((B c)(x))

at the painted map's own resolution, with B the bilinear interpolation of the
cell values (cell centres at the centres of an n×n grid laid over the same
extent, map convention, clamped at the edges).  Detail the artist painted stays
where it was; the fit moves its colour, patch by patch.  With no painted map
(or when the user asks for a fresh grid) M is the painted map area-averaged to
n×n, or white, and B the identity.

The neighbour differences c_i − c_j over 4-neighbour cells carry the prior
(:mod:`.solve`): by default (``map_prior = "edges"``) a Huber penalty — quadratic
below a small step, linear above, so an edge costs its height once (total
variation; Rudin, Osher & Fatemi 1992) — with a weak prior per cell, so a sharp
painted pattern can be recovered wherever the reference sees it; or
(``"smooth"``, earlier versions) a first-difference Tikhonov penalty (Tikhonov
1963) that keeps the field smooth and forbids patches.

A pixel's colour depends on the (at most 2×2) cells around its hit's world
position, so the image's derivative with respect to all cells is measured in
nine forward-mode renders, one per class (i mod 3, j mod 3) of cells: no two
cells of a class touch the same pixel (:func:`cell_classes`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def _axis_weights(n_out: int, n_cells: int) -> sp.csr_matrix:
    """(n_out, n_cells) linear interpolation from cell centres to output texel centres (clamped)."""
    x = (np.arange(n_out) + 0.5) * n_cells / n_out - 0.5
    x = np.clip(x, 0.0, n_cells - 1)
    i0 = np.floor(x).astype(np.int64)
    i1 = np.minimum(i0 + 1, n_cells - 1)
    f = x - i0
    rows = np.r_[np.arange(n_out), np.arange(n_out)]
    return sp.csr_matrix((np.r_[1 - f, f], (rows, np.r_[i0, i1])), shape=(n_out, n_cells))


def upsample_operator(shape: tuple[int, int], cells: tuple[int, int]) -> sp.csr_matrix:
    """B: (H·W, n·m) bilinear interpolation of an n×m cell field onto an H×W map (row-major)."""
    wy = _axis_weights(shape[0], cells[0])
    wx = _axis_weights(shape[1], cells[1])
    return sp.kron(wy, wx, format="csr")


def smoothness_operator(cells: tuple[int, int]) -> sp.csr_matrix:
    """D: first differences between 4-neighbour cells, ((n−1)m + n(m−1), n·m)."""
    n, m = cells
    idx = np.arange(n * m).reshape(n, m)
    pairs = [(idx[:, :-1].ravel(), idx[:, 1:].ravel()), (idx[:-1, :].ravel(), idx[1:, :].ravel())]
    a = np.concatenate([p[0] for p in pairs])
    b = np.concatenate([p[1] for p in pairs])
    k = len(a)
    rows = np.r_[np.arange(k), np.arange(k)]
    return sp.csr_matrix((np.r_[np.ones(k), -np.ones(k)], (rows, np.r_[a, b])), shape=(k, n * m))


def cell_classes(cells: tuple[int, int]) -> np.ndarray:
    """(n, m) class 0..8 of each cell: 3·(i mod 3) + (j mod 3)."""
    n, m = cells
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    return (3 * (i % 3) + (j % 3)).astype(np.int64)


def pixel_cells(u: np.ndarray, v: np.ndarray, cells: tuple[int, int]) -> np.ndarray:
    """For pixels hitting map coordinates (u, v) ∈ [0, 1]² (NaN: no hit): (P, 9) the index of the cell of
    each class that can touch the pixel (−1 none).  Cells touch a point within one cell of their centre."""
    n, m = cells
    fi = v * n - 0.5  # cell-centre coordinates
    fj = u * m - 0.5
    ok = np.isfinite(fi) & np.isfinite(fj)
    i0 = np.where(ok, np.floor(np.nan_to_num(fi)), -10).astype(np.int64)
    j0 = np.where(ok, np.floor(np.nan_to_num(fj)), -10).astype(np.int64)
    out = np.full((len(u), 9), -1, np.int64)
    for di in (0, 1):
        for dj in (0, 1):
            i = np.clip(i0 + di, 0, n - 1)
            j = np.clip(j0 + dj, 0, m - 1)
            good = ok & (i0 + di >= -1) & (j0 + dj >= -1)
            k = 3 * (i % 3) + (j % 3)
            rows = np.flatnonzero(good)
            out[rows, k[rows]] = (i * m + j)[rows]
    return out


def base_map(painted: np.ndarray | None, cells: tuple[int, int], fresh: bool) -> np.ndarray:
    """M: the painted map (linear RGB) at its own resolution, or area-averaged to the cells (fresh / none).

    A painted map coarser than the cells (a uniform 1×1 grey, say) is first sampled onto the cells' resolution
    as the renderer samples it (bilinear between texel centres, clamped), so it renders the same and the fitted
    map keeps the cells' detail."""
    if painted is None:
        return np.ones((*cells, 3))
    m = np.asarray(painted, np.float64)
    if fresh:
        from ..images import resample

        return np.asarray(resample(m.astype(np.float32), cells[0], cells[1]), np.float64)
    if m.shape[0] < cells[0] or m.shape[1] < cells[1]:
        from ..maps import sample_bilinear

        h, w = max(m.shape[0], cells[0]), max(m.shape[1], cells[1])
        u, v = np.meshgrid((np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h)
        m = np.asarray(sample_bilinear(m, u.ravel(), v.ravel()), np.float64).reshape(h, w, 3)
    return m


def corrected(base: np.ndarray, correction: np.ndarray | None, op: sp.csr_matrix | None = None) -> np.ndarray:
    """M · exp(B c) at M's resolution (B built here when not given)."""
    if correction is None:
        return base
    h, w = base.shape[:2]
    op = upsample_operator((h, w), correction.shape[:2]) if op is None else op
    field = op @ correction.reshape(-1, 3)
    return base * np.exp(field).reshape(h, w, 3)
