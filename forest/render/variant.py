"""Which Mitsuba variant renders a scene, and why.

An explicit request wins, then ``[render] variant``.  Otherwise: Mitsuba
3.9.1 builds instanced scenes in time quadratic in the instance count in its
JIT variants and linear in ``scalar_rgb``; so a GPU (``cuda_ad_rgb``) for
small forests when one is present, else ``scalar_rgb``.
"""

from __future__ import annotations

from ..errors import ParameterError
from ..runtime import VARIANTS, cuda_available

#: A GPU renders forests up to this many trees faster than the CPU; above it the
#: quadratic instancing cost of the JIT variants in Mitsuba 3.9.1 dominates.
CUDA_MAX_TREES = 2000


def check_variant(variant: str) -> str:
    """``variant`` if this machine can render with it; a :class:`ParameterError` naming ``variant`` otherwise."""
    if variant not in VARIANTS:
        raise ParameterError("variant", f"must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if variant == "cuda_ad_rgb" and not cuda_available():
        raise ParameterError("variant", "cuda_ad_rgb needs an NVIDIA GPU and driver, none found")
    return variant


def choose_variant(trees: int, requested: str | None = None, configured: str | None = None) -> tuple[str, str]:
    """The variant to render ``trees`` trees with, and the reason (see the module docstring)."""
    for v, why in ((requested, "requested"), (configured, "[render] variant")):
        if v is not None:
            check_variant(v)
            if v != "scalar_rgb" and trees > CUDA_MAX_TREES:
                why += (
                    f"; note: {trees:,} instances in a JIT variant build in quadratic time in "
                    "Mitsuba 3.9.1 — scalar_rgb is much faster for this forest"
                )
            return v, why
    if cuda_available() and trees <= CUDA_MAX_TREES:
        return "cuda_ad_rgb", f"GPU found and {trees:,} trees ≤ {CUDA_MAX_TREES:,}"
    return "scalar_rgb", (
        f"{trees:,} trees: instancing is linear in scalar_rgb, quadratic in the JIT variants of Mitsuba 3.9.1"
    )
