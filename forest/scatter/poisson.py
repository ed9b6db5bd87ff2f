"""Poisson-disk (blue-noise) thinning of scattered points, exact and vectorised.

Given candidates in priority order, keep a point iff no *kept* point with a
higher priority lies within ``r`` — the result of sequential dart throwing
(Cook 1986) over that order, which is a maximal set with minimum spacing ``r``.

The sequential rule is resolved in parallel rounds over the conflict graph
(pairs closer than ``r``, found with a KD-tree): in each round a point whose
higher-priority neighbours are all rejected is accepted, and a point with an
accepted higher-priority neighbour is rejected.  The outcome equals the
sequential one exactly; the number of rounds is the longest decision chain,
which for random priorities grows like log n.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

UNDECIDED, ACCEPTED, REJECTED = 0, 1, 2


def conflict_pairs(points: np.ndarray, r: float) -> np.ndarray:
    """Index pairs (i, j), i < j, of points closer than ``r``; int64 (m, 2)."""
    if len(points) < 2 or r <= 0:
        return np.zeros((0, 2), dtype=np.int64)
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    return tree.query_pairs(r, output_type="ndarray").astype(np.int64)


def poisson_thin(points: np.ndarray, r: float) -> np.ndarray:
    """Boolean mask of the points kept so that kept points are ≥ ``r`` apart.

    ``points`` (n, d) are in priority order (index 0 first).  Exact equivalent
    of greedy sequential dart throwing over that order.
    """
    n = len(points)
    state = np.zeros(n, dtype=np.uint8)
    pairs = conflict_pairs(points, r)
    if len(pairs) == 0:
        return np.ones(n, dtype=bool)
    hi = np.minimum(pairs[:, 0], pairs[:, 1])  # higher priority (earlier)
    lo = np.maximum(pairs[:, 0], pairs[:, 1])
    # Points in no conflict with an earlier point are accepted at once.
    has_earlier = np.zeros(n, dtype=bool)
    has_earlier[lo] = True
    state[~has_earlier] = ACCEPTED
    while len(hi):
        s_hi = state[hi]
        # A later point with an accepted earlier neighbour is rejected.
        rej = np.zeros(n, dtype=bool)
        rej[lo[s_hi == ACCEPTED]] = True
        state[rej & (state == UNDECIDED)] = REJECTED
        # Drop pairs whose earlier end is rejected (no constraint) or whose later end is decided.
        keep = (state[hi] != REJECTED) & (state[lo] == UNDECIDED)
        hi, lo = hi[keep], lo[keep]
        # Undecided points with no remaining constraining neighbour are accepted.
        blocked = np.zeros(n, dtype=bool)
        blocked[lo] = True
        state[(state == UNDECIDED) & ~blocked] = ACCEPTED
    return state == ACCEPTED
