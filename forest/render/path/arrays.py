"""numpy tables and scene parameters as drjit arrays in memory drjit owns, so one scene compiles to one kernel.

In ``llvm_ad_rgb``, constructing ``mi.Float(a)`` from a numpy array maps ``a``'s
buffer without a copy (drjit 1.5: the drjit array aliases the numpy memory) and
flags it *unaligned* unless its address is a multiple of 64 bytes; ``dr.copy``
keeps the flag.  A gather of 2, 4 or 8 consecutive values
(``dr.gather(mi.Vector4f, …)``, a texture's texels) from an aligned source
compiles to one packet load, from an unaligned one to separate loads — so the
path kernel's code, and with it drjit's kernel hash, depended on where numpy's
allocator (16-byte aligned) happened to place each table.  The same scene
compiled a new kernel on most runs (0.7–1.6 s each) and drjit's on-disk kernel
cache rarely hit.  :func:`owned` evaluates the table into a buffer drjit
allocates (aligned), which also ends the aliasing: a later change to the numpy
array no longer reaches the renderer.  In ``cuda_ad_rgb`` the constructor
already copies to the device, and nothing more is done.

**Reading past the end.** drjit's LLVM kernels load whole packets of 16 lanes (an unmasked
``vmovdqu64`` on AVX-512), so the last packet of an array whose length is not a multiple of 16 reads
up to 15 elements past its end — past the end of an aliased numpy buffer too. numpy's large buffers
are pages of their own (``mmap``), and when such a buffer ends within a packet of a page that is not
mapped the kernel faults: the demo crashed (SIGSEGV in a kernel thread, in ``owned``'s copy of
a 6.4-million-element table) on about half its renders, depending on where the allocator put the
table. :func:`mappable` gives drjit a view of a buffer :data:`SLACK` elements longer than the array,
so the packet's excess stays in memory numpy owns; every numpy array this package hands drjit in a
JIT variant goes through it (:func:`owned` too).

A scene parameter made from Python numbers (``mi.Color3f(r, g, b)``, ``mi.Float(x)``)
is a *literal*: its value is written into the code of every kernel that reads it,
so each new value compiles a new kernel.  Look-dev sets its lights, tints and haze
to new values at every step and rendered each step's held-out view with a kernel
compiled for it (17 path kernels compiled in one fit of the demo, 1.0–1.6 s each).
:func:`opaque` keeps such a value in memory instead: a kernel parameter, one
kernel for every value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Elements of memory after the end of a numpy buffer that drjit reads (:func:`mappable`).
SLACK = 32


def mappable(data: Any) -> np.ndarray:
    """``data`` as a C-contiguous numpy array followed by :data:`SLACK` elements of its own memory: a view of the
    first ``size`` elements of a larger buffer, for drjit to alias (module docstring, "Reading past the end")."""
    a = np.asarray(data)
    buf = np.empty(a.size + SLACK, dtype=a.dtype)
    buf[: a.size] = a.ravel()
    return buf[: a.size].reshape(a.shape)


def opaque(cls: Any, *values: float) -> Any:
    """``cls(*values)`` (``mi.Float``, ``mi.Color3f``, …) held in memory: a kernel parameter, not a literal."""
    import drjit as dr

    value = cls(*(float(v) for v in values))
    dr.make_opaque(value)
    return value


def owned(cls: Any, data: Any) -> Any:
    """``data`` (array-like) as a ``cls`` array (``mi.Float``, ``mi.UInt32``, ``mi.TensorXf``, …) drjit owns."""
    import drjit as dr

    a = mappable(data)
    arr = cls(a)
    if dr.backend_v(arr) != dr.JitBackend.LLVM or a.size == 0:
        return arr
    flat = arr.array if dr.is_tensor_v(arr) else arr
    idx = dr.arange(dr.uint32_array_t(type(flat)), dr.width(flat))
    copy = dr.empty(type(flat), dr.width(flat))
    dr.scatter(copy, flat, idx)
    dr.eval(copy)
    return cls(copy, a.shape) if dr.is_tensor_v(arr) else copy
