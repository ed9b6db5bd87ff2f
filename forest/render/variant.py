"""Which Mitsuba variant renders a scene, and why.

An explicit request wins, then ``[render] variant``.  Otherwise the renderer
that is faster *for the same look* on this machine:

* a GPU present (an NVIDIA driver) that passed the self-check
  (:mod:`forest.render.selfcheck`: forest_path renders a tiny forest in
  ``cuda_ad_rgb``, in a child process, finite and not black, within
  :data:`~forest.render.selfcheck.TIME_LIMIT_S`; the result is cached per GPU,
  driver and Mitsuba): ``cuda_ad_rgb`` — forest_path, the same code as in
  ``llvm_ad_rgb``, on the GPU;
* else ``llvm_ad_rgb`` — forest_path on the CPU (``scalar_rgb`` without LLVM 19);
  where the GPU failed its self-check the reason says why, and how to force it.

The look is forest's: leaves that transmit light and cast card-shaped
(alpha-cut) shadows, a finite sun.  ``scalar_rgb`` renders it with Mitsuba's
``volpath`` (``[render] alpha_shadows``, on by default) and ``principledthin``
leaves.  Measured with ``bench/bench_render.py`` (CPU seconds of
``render_scene``: scene build, beauty, coverage and Cryptomattes, layers,
EXR and PNG; max_depth 3, on a 2-core machine shared with other work, load
average 4.5–6.6):

* ``--case scale`` — the default look, 320×180, 16 spp, 1 000 / 10 000 /
  50 000 / 130 000 trees, two runs: scalar_rgb took 2.15× / 1.91× / 1.90× /
  1.87× and 2.00× / 1.99× / 1.86× / 1.84× forest_path's CPU time (wall
  1.35–3.4×, noisier), peak memory 0.61–1.62 GB against 0.54–1.34 GB;
* ``--case original`` — the case study's 130 000 trees through ``forest
  render`` at 480×270, 64 spp: 119 against 52 CPU-s (2.29×), 11.8 against
  4.9 CPU-µs per sample (2.4×);
* ``--case look`` — each feature over the plain render (10 000 trees,
  320×180, a view to the horizon).  At 64 spp forest_path and scalar_rgb's plain ``path``
  cost the same per sample (0.87–1.08× for every feature but one); the
  difference is the alpha-cut shadows: ``volpath`` costs 2.2× the plain
  render, forest_path traces them always at no extra cost.  The full look:
  2.02× (64 spp), 1.86× and 1.88× (16 spp, two runs).

So :data:`SCALAR_COST` is 1.8–2.4 for the look forest renders by default,
and scalar_rgb was never the faster at equal samples for it; it is chosen
only when asked (with ``alpha_shadows = false`` — cards shadowing as
rectangles — it costs about what forest_path does).
It stays for what it alone does: Mitsuba's own integrators and BSDFs
as an independent reference renderer (``tests/test_forest_path.py`` and
``tests/test_render_pipeline.py`` compare the two).  It is no way round a
scene too large for forest_path: its coverage, id and depth layers come from
forest_path's traversal of the same forest (:mod:`forest.render.frame`), so it
holds that scene too.
"""

from __future__ import annotations

from ..errors import ParameterError
from ..runtime import VARIANTS, cuda_available, find_llvm, gpu_info

#: scalar_rgb's CPU time over forest_path's (llvm_ad_rgb) for forest's default look, the range measured by
#: ``bench/bench_render.py --case scale`` (1 000 to 130 000 trees), ``--case original`` and ``--case look`` (see the
#: module docstring).
SCALAR_COST = "1.8-2.4"
#: What the choice rests on, in a few words (the measurements are in the module docstring and docs/rendering.md).
MEASURED = f"{SCALAR_COST}x faster than scalar_rgb for forest's look"


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


def gpu_passes() -> tuple[bool, str]:
    """Whether the automatic choice may take the GPU, and why: a GPU is present and passed its self-check
    (run now if this machine, driver and Mitsuba have no stored result)."""
    if not cuda_available():
        return False, "no GPU"
    from .selfcheck import gpu_selfcheck  # here: `python -m forest.render.selfcheck` imports forest.render first

    check = gpu_selfcheck()
    return check.ok, check.reason


def gpu_check_pending() -> bool:
    """True when the automatic choice would first run the GPU self-check (a GPU present, no result stored for it):
    a command says so before it waits for it."""
    if not cuda_available():
        return False
    from .selfcheck import pending

    return pending()


def _gpu_failed(reason: str, fallback: str) -> str:
    return f"GPU self-check failed: {reason}; using {fallback} — force the GPU with --variant cuda_ad_rgb"


def default_variant(trees: int | None = None) -> tuple[str, str]:
    """The automatic choice on this machine (no request, no ``[render] variant``) and the reason; ``trees`` only
    words the reason."""
    ok, why = gpu_passes()
    many = "" if trees is None else f" ({trees:,} trees)"
    if ok:
        return "cuda_ad_rgb", f"GPU found and its self-check passed: forest_path on the GPU{many}"
    if find_llvm() is None:
        fallback, reason = "scalar_rgb", "no LLVM 19 for the JIT variants: Mitsuba's scalar_rgb"
    else:
        fallback, reason = "llvm_ad_rgb", f"no GPU: forest_path on the CPU, {MEASURED}"
    return fallback, reason if why == "no GPU" else _gpu_failed(why, fallback)


def default_jit_variant() -> tuple[str, str]:
    """The automatic choice among the JIT variants (look-dev differentiates, so never ``scalar_rgb``): the GPU where
    it passed its self-check, else ``llvm_ad_rgb``."""
    ok, why = gpu_passes()
    if ok:
        return "cuda_ad_rgb", "GPU found and its self-check passed"
    return "llvm_ad_rgb", "no GPU" if why == "no GPU" else _gpu_failed(why, "llvm_ad_rgb")


def capability() -> dict[str, str | int | None]:
    """What this process renders with when a job names no variant, for the job service's worker list:
    ``variant`` and ``variant_reason`` (:func:`default_variant`) and, with a GPU, its name (``gpu``) and memory
    (``gpu_memory_mib``), else None."""
    v, why = default_variant()
    gpu = gpu_info()
    return {
        "variant": v,
        "variant_reason": why,
        "gpu": gpu.name if gpu is not None else None,
        "gpu_memory_mib": gpu.memory_mib if gpu is not None else None,
    }


def choose_variant(trees: int, requested: str | None = None, configured: str | None = None) -> tuple[str, str]:
    """The variant to render ``trees`` trees with, and the reason (see the module docstring).

    An explicit variant (``requested``, then ``configured``) is checked and taken, with no GPU self-check."""
    for v, why in ((requested, "requested"), (configured, "[render] variant")):
        if v is not None:
            check_variant(v)
            return v, why
    return default_variant(trees)
