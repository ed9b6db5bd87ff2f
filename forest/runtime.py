"""Mitsuba / drjit runtime set-up: LLVM discovery and variant selection.

drjit 1.5's CPU backend needs LLVM 19 (LLVM 14–16 crash with
``Cannot select: fminimum``).  :func:`ensure_llvm` finds ``libLLVM-19.so`` and
names it in ``DRJIT_LIBLLVM_PATH`` before mitsuba is imported;
:func:`mitsuba` imports mitsuba with a variant set and our plugins registered.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from .errors import ForestError, ParameterError

VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")

_LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/llvm-19/lib/libLLVM-19.so",
    "/usr/lib/llvm-19/lib/libLLVM.so.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so",
    "/usr/local/lib/libLLVM-19.so",
)


def find_llvm() -> str | None:
    """Return the path of an LLVM 19 shared library, or None."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and Path(env).is_file():
        return env
    stamp = Path(sys.prefix) / "llvm-path"
    if stamp.is_file():
        p = stamp.read_text().strip()
        if Path(p).is_file():
            return p
    for p in _LLVM_CANDIDATES:
        if Path(p).is_file():
            return p
    return None


def ensure_llvm() -> str:
    """Point drjit at LLVM 19; raise a clear error if it is not installed."""
    path = find_llvm()
    if path is None:
        raise ForestError(
            "LLVM 19 not found: install the Debian package libllvm19 (scripts/setup.sh does) "
            "or set DRJIT_LIBLLVM_PATH to libLLVM-19.so"
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def cuda_available() -> bool:
    """True when an NVIDIA driver is present (cheap check, no CUDA context)."""
    return any(Path(p).exists() for p in ("/dev/nvidia0", "/proc/driver/nvidia/version"))


_current: str | None = None


def mitsuba(variant: str = "scalar_rgb"):
    """Import mitsuba with ``variant`` set and forest's plugins registered; return the module."""
    global _current
    if variant not in VARIANTS:
        raise ParameterError("variant", f"must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if variant.startswith("llvm"):
        ensure_llvm()
    else:
        find = find_llvm()
        if find:
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", find)
    import mitsuba as mi

    if _current != variant:
        try:
            mi.set_variant(variant)
        except Exception as e:
            raise ForestError(f"cannot use Mitsuba variant {variant}: {e}") from None
        _current = variant
        try:
            from forest.plugins import register_all
        except ImportError:
            register_all = None
        if register_all is not None:
            register_all(mi)
    return mi
