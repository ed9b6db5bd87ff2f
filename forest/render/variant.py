"""Which Mitsuba variant renders a scene, and why.

An explicit request wins, then ``[render] variant``.  Otherwise the renderer
that is faster *for the same look* on this machine:

* a GPU present (an NVIDIA driver): ``cuda_ad_rgb`` — forest_path, the same
  code as in ``llvm_ad_rgb``, on the GPU;
* else ``llvm_ad_rgb`` — forest_path on the CPU.

The look is forest's: leaves that transmit light and cast card-shaped
(alpha-cut) shadows, a finite sun.  ``scalar_rgb`` renders it with Mitsuba's
``volpath`` (``[render] alpha_shadows``, on by default) and ``principledthin``
leaves; measured with ``bench/bench_render.py`` on the 2-core machine of the
benchmark table, scalar_rgb took :data:`SCALAR_COST` times forest_path's CPU
time for that look, from a few trees to 130 000 (see :data:`MEASURED`), and
it was never the faster at equal samples — so it is chosen only when asked.
It stays for what it alone does: Mitsuba's own integrators and BSDFs as an
independent reference (``tests/test_forest_path.py`` compares the two), and
scenes whose JIT scene would not fit in memory while the scalar one does.
"""

from __future__ import annotations

from ..errors import ParameterError
from ..runtime import VARIANTS, cuda_available, find_llvm

#: scalar_rgb's CPU time over forest_path's (llvm_ad_rgb) for the same look, range measured by
#: ``bench/bench_render.py --case look`` (see :data:`MEASURED`).
SCALAR_COST = "1.9-3.4"
#: What the choice rests on, printed with it.
MEASURED = (
    "forest_path renders forest's look (leaf transmission, alpha-cut shadows, disc sun) in "
    f"{SCALAR_COST}x less CPU time than scalar_rgb's volpath (bench/bench_render.py)"
)


def check_variant(variant: str) -> str:
    """``variant`` if this machine can render with it; a :class:`ParameterError` naming ``variant`` otherwise."""
    if variant not in VARIANTS:
        raise ParameterError("variant", f"must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if variant == "cuda_ad_rgb" and not cuda_available():
        raise ParameterError("variant", "cuda_ad_rgb needs an NVIDIA GPU and driver, none found; use llvm_ad_rgb")
    if variant == "llvm_ad_rgb" and find_llvm() is None:
        raise ParameterError(
            "variant", "llvm_ad_rgb needs LLVM 19 (Debian package libllvm19), not found; use scalar_rgb"
        )
    return variant


def choose_variant(trees: int, requested: str | None = None, configured: str | None = None) -> tuple[str, str]:
    """The variant to render ``trees`` trees with, and the reason (see the module docstring)."""
    for v, why in ((requested, "requested"), (configured, "[render] variant")):
        if v is not None:
            check_variant(v)
            return v, why
    if cuda_available():
        return "cuda_ad_rgb", f"GPU found: forest_path on the GPU ({trees:,} trees)"
    if find_llvm() is None:
        return "scalar_rgb", "no LLVM 19 for the JIT variants: Mitsuba's scalar_rgb"
    return "llvm_ad_rgb", f"no GPU: forest_path on the CPU; {MEASURED}"
