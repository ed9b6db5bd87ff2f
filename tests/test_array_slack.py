"""numpy arrays handed to drjit keep memory of their own after their end (``forest.render.path.arrays``,
"Reading past the end"): drjit's LLVM kernels load whole 16-lane packets, and an aliased numpy buffer
that ends just before an unmapped page made the last packet fault (the demo crashed on about half its
renders). Here the array really ends at a guard page (``mmap`` + ``mprotect``), in a subprocess so that
a regression is a failed test and not a crashed test run."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np

from forest.render.path.arrays import SLACK, mappable

GUARDED = textwrap.dedent(
    """
    import ctypes, mmap
    import numpy as np
    import mitsuba as mi
    import drjit as dr

    mi.set_variant("llvm_ad_rgb")
    from forest.render.path.arrays import mappable, owned

    page, pages = mmap.PAGESIZE, 16
    libc = ctypes.CDLL(None)
    libc.mmap.restype = ctypes.c_void_p
    libc.mmap.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_long]
    libc.mprotect.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
    base = libc.mmap(None, (pages + 1) * page, 3, 0x22, -1, 0)  # read/write, private anonymous
    assert libc.mprotect(base + pages * page, page, 0) == 0  # the page after the array: no access
    n = (pages * page - 12) // 4
    a = np.frombuffer((ctypes.c_float * n).from_address(base + 12), dtype=np.float32)
    assert n % 16 and a.ctypes.data + a.nbytes == base + pages * page  # ends right at the guard page
    a[:] = np.arange(n) % 7
    want = float(a.astype(np.float64).sum())
    got = [dr.sum(owned(mi.Float, a) * 2.0), dr.sum(mi.Float(mappable(a)) + 1.0)]
    t = mi.TensorXf(mappable(a.reshape(1, n)))
    got.append(dr.sum(t.array))
    print(*(float(g[0] if hasattr(g, "__len__") else g) for g in got), want * 2, want + n, want)
    """
)


def test_mappable_is_the_array_with_slack_after_it():
    a = np.arange(12, dtype=np.float32).reshape(3, 4)[:, ::2]  # not contiguous
    m = mappable(a)
    assert m.flags.c_contiguous and m.shape == a.shape and m.dtype == a.dtype
    np.testing.assert_array_equal(m, a)
    assert m.base is not None and m.base.size >= a.size + SLACK
    assert mappable(np.zeros(0, np.uint32)).size == 0


def test_arrays_ending_at_an_unmapped_page_are_read_safely():
    """owned() and mappable() arrays whose source ends at a guard page: no fault, the right sums."""
    r = subprocess.run([sys.executable, "-c", GUARDED], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    got = [float(v) for v in r.stdout.split()]
    assert got[0] == got[3] and got[1] == got[4] and got[2] == got[5]


def test_no_numpy_array_reaches_drjit_without_slack():
    """A guard on the source: no ``mi.Float(np.…)``, ``mi.TensorXf(x.astype(…))`` or the like outside
    ``mappable`` / ``owned`` in the package (such a call aliases the numpy buffer with no slack after it)."""
    import re
    from pathlib import Path

    import forest

    pattern = re.compile(r"mi\.(Float|UInt32|Int32|UInt64|Float64|Bool|TensorXf)\((np\.|\w+\.astype\(|\w+\.ravel\(\))")
    root = Path(forest.__file__).parent
    found = [
        f"{path.relative_to(root)}:{n}: {line.strip()}"
        for path in sorted(root.rglob("*.py"))
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if pattern.search(line)
    ]
    assert not found, "numpy arrays handed to drjit without forest.render.path.arrays.mappable:\n" + "\n".join(found)
