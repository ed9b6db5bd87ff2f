"""Row-wise numpy work split over the machine's cores, with results identical to one call.

numpy runs an element-wise operation on one core but releases the GIL while it
does, so a function whose output row i depends only on input row i (a terrain
lookup, a colour conversion per tree) can run on contiguous blocks of rows in
threads and the blocks be concatenated: the same operations on the same values
in the same order per row, so the result is the same to the bit whatever the
number of threads.  :func:`rowwise` does that for inputs of at least
:data:`MIN_ROWS` rows (below it a thread costs more than it saves).  The
function must be safe to call from several threads at once: it may read shared
arrays but must not fill a cache on first use (warm such caches before).
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from functools import lru_cache
from typing import Any

import numpy as np

#: Fewest rows worth splitting.
MIN_ROWS = 100_000
_PREFIX = "forest-rows"


def workers() -> int:
    """Cores this process may run on (its CPU affinity), at most 8."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        n = os.cpu_count() or 1
    return max(1, min(8, n))


@lru_cache(maxsize=1)
def _pool() -> ThreadPoolExecutor:
    return ThreadPoolExecutor(max_workers=workers(), thread_name_prefix=_PREFIX)


# A forked child has none of its parent's threads: it makes its own pool on first use.
if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_pool.cache_clear)


def _bounds(n: int, min_rows: int | None) -> np.ndarray | None:
    """Block edges 0 = b₀ < … < b_k = n for ``n`` rows, or None for one call: under ``min_rows`` rows (default
    :data:`MIN_ROWS`) a block, on one core, or already on a block (a nested split would wait on its own pool)."""
    if threading.current_thread().name.startswith(_PREFIX):
        return None
    k = min(workers(), max(1, n // max(1, MIN_ROWS if min_rows is None else min_rows)))
    return None if k <= 1 else np.linspace(0, n, k + 1).astype(np.int64)


def rowwise(fn: Callable[..., Any], *arrays: np.ndarray, min_rows: int | None = None) -> Any:
    """``fn(*arrays)`` computed on blocks of rows in threads and concatenated along axis 0.

    Every array has the same number of rows N (axis 0); ``fn`` returns an array of N rows or a
    tuple of them, row i depending only on the inputs' row i.  One call when N < ``min_rows``
    (default :data:`MIN_ROWS`), on one core, or when called from one of the blocks (nested).
    """
    bounds = _bounds(len(arrays[0]), min_rows)
    if bounds is None:
        return fn(*arrays)
    futures = [_pool().submit(fn, *(a[lo:hi] for a in arrays)) for lo, hi in itertools.pairwise(bounds)]
    parts = [f.result() for f in futures]
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(p, axis=0) for p in zip(*parts))
    return np.concatenate(parts, axis=0)


def blockwise(fn: Callable[[int, int], None], n: int, *, min_rows: int | None = None) -> None:
    """``fn(lo, hi)`` on contiguous blocks of rows ``[lo, hi)`` covering ``range(n)``, in threads.

    For work done *in place*: ``fn`` updates rows lo…hi − 1 of arrays it holds (views, so each block
    writes its own rows) and row i's update depends only on row i of its inputs, so the result is
    the same to the bit as ``fn(0, n)``.  One call when n < ``min_rows`` (default :data:`MIN_ROWS`),
    on one core, or when called from one of the blocks (nested), as :func:`rowwise`.
    """
    bounds = _bounds(n, min_rows)
    if bounds is None:
        fn(0, n)
        return
    for f in [_pool().submit(fn, int(lo), int(hi)) for lo, hi in itertools.pairwise(bounds)]:
        f.result()
