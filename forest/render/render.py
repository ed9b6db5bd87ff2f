"""``render_scene``: a Scene rendered with Mitsuba 3 — stills, fly-throughs, motion blur — to EXR + PNG.

The variant comes from :func:`forest.render.variant.choose_variant`; the
frames from forest_path in the JIT variants
(:class:`forest.render.jit_frame.PathFrameRenderer`) and from Mitsuba's own
integrators in ``scalar_rgb`` (:class:`forest.render.frame.FrameRenderer`):
camera, levels of detail, sub-frames, sample passes, coverage, Cryptomattes,
depth/id/species, haze.  Each frame is written by
:func:`forest.render.output.write_frame`: a comp-ready float EXR (RGBA,
data layers, Cryptomattes, camera matrices, colour space; settings and
deterministic scene statistics in the header) and a PNG through the view
transform (``[render] view``, ``exposure``).
"""

from __future__ import annotations

import math
import resource
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from ..errors import ParameterError
from ..frames import frame_path, parse_frames, still_path
from ..imaging.denoise import denoise_rule
from ..scene import Scene
from .frame import FrameRenderer, FrameSize
from .jit_frame import PathFrameRenderer
from .output import write_frame
from .variant import choose_variant

Renderer = FrameRenderer | PathFrameRenderer  # both are forest.render.loop.Backend

PREVIEW_WIDTH = 480
PREVIEW_SPP = 8

#: ``on_pass(frame, image so far, passes done, passes in the frame)`` — a live view of each frame.
FramePassCallback = Callable[[int, np.ndarray, int, int], None]


@dataclass
class RenderResult:
    """What a render wrote and what it cost."""

    paths: list[Path]  # every file written (EXR and PNG per frame)
    frames: list[int]
    variant: str
    variant_reason: str
    width: int
    height: int
    spp: int
    subframes: int
    trees: int
    instanced_triangles: int
    unique_triangles: int
    shapegroups: int
    load_seconds: float
    render_seconds: float
    peak_memory_gb: float
    lod_counts: dict[str, int] = field(default_factory=dict)
    denoised: bool = False
    leaf_model: str = ""
    lod_rule: str = ""  # the rule that chose the levels (:meth:`forest.lod.LodPlan.describe`)
    gpu_peak_gb: float | None = None  # cuda_ad_rgb: drjit's peak device memory (its allocator's watermark)
    denoise_rule: str = ""  # why the frames were (not) denoised (:func:`forest.imaging.denoise.denoise_rule`)

    def summary(self) -> str:
        """One line: trees, instanced and unique triangles, times, peak memory, the levels and their rule, and
        whether ``[render] denoise`` denoised the frames and why (``"auto"`` says so when it stayed off)."""
        frames = f"{len(self.frames)} frames" if len(self.frames) > 1 else "1 frame"
        lod = ""
        if self.lod_counts:
            counts = ", ".join(f"{k} {v:,}" for k, v in self.lod_counts.items())
            lod = f"; LOD {counts}" + (f" ({self.lod_rule})" if self.lod_rule else "")
        return (
            f"rendered {frames} {self.width}x{self.height} {self.spp} spp ({self.variant}): "
            f"{self.trees:,} trees, {self.instanced_triangles:,} instanced triangles, "
            f"{self.unique_triangles:,} unique, load {self.load_seconds:.1f} s, "
            f"render {self.render_seconds:.1f} s, peak {self.peak_memory_gb:.2f} GiB"
            + (f" (GPU {self.gpu_peak_gb:.2f} GiB)" if self.gpu_peak_gb is not None else "")
            + lod
            + (f"; {'' if self.denoised else 'not '}denoised ({self.denoise_rule})" if self.denoise_rule else "")
        )


def gpu_peak_gb(variant: str) -> float | None:
    """Peak GPU memory drjit's CUDA allocator held in this process, GiB (None outside ``cuda_ad_rgb``)."""
    if variant != "cuda_ad_rgb":
        return None
    import drjit as dr

    return float(dr.detail.malloc_watermark(dr.JitBackend.CUDA)) / 2**30


def peak_memory_gb() -> float:
    """Peak resident memory of this process, GiB (getrusage ru_maxrss, KiB on Linux), as the pre-flight's
    estimate is printed."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def output_paths(output: str | Path) -> tuple[Path, Path]:
    """(EXR, PNG) for an output name ending in .exr or .png; a :class:`ParameterError` on ``output`` otherwise."""
    out = Path(output)
    ext = out.suffix.lower()
    if ext == ".exr":
        return out, out.with_suffix(".png")
    if ext == ".png":
        return out.with_suffix(".exr"), out
    raise ParameterError("output", f"{output}: the output must end in .exr (an sRGB .png is written beside it)")


def frame_size(config: Config, *, preview: bool) -> FrameSize:
    """The render's size: ``[render]``, or the preview's (≤ 480 px wide, ≤ 8 spp, no motion blur)."""
    rc = config.render
    if preview:
        k = min(1.0, PREVIEW_WIDTH / rc.width)
        return FrameSize(max(1, round(rc.width * k)), max(1, round(rc.height * k)), min(rc.spp, PREVIEW_SPP), 1)
    return FrameSize(rc.width, rc.height, rc.spp, rc.subframes if config.camera.shutter > 0 else 1)


def make_renderer(
    scene: Scene,
    variant: str,
    size: FrameSize,
    *,
    preview: bool = False,
    progress: Callable[[float, str], None] | None = None,
    frame: float = 1.0,
) -> Renderer:
    """The frame renderer of ``variant``: forest_path in the JIT variants, Mitsuba's integrators in scalar_rgb.

    ``progress(fraction, step)`` follows forest_path's scene build step by step; forest_path builds its scene in
    the pose of ``frame``, the first frame it will render (scalar_rgb builds at its first frame anyway)."""
    if variant.startswith("scalar"):
        return FrameRenderer(scene, variant, size, preview=preview)
    return PathFrameRenderer(scene, variant, size, preview=preview, progress=progress, frame=frame)


def build_share(variant: str, trees: int, size: FrameSize, frames: int) -> float:
    """The part of a render's time its scene build takes, as this machine's render rates forecast it
    (:func:`forest.preflight.throughput`), between 0.05 and 0.95: where the build ends on the progress bar."""
    from ..preflight import throughput

    sample_s, tree_s, _ = throughput(variant)
    build = 1.0 + trees * tree_s  # a second for Mitsuba and the terrain, then the trees
    samples = size.width * size.height * max(size.spp, size.subframes) * max(1, frames)
    return min(0.95, max(0.05, build / (build + samples * sample_s)))


def _kept(reuse: dict[str, Any] | None, key: tuple[Any, ...], build: Callable[[], Renderer]) -> Renderer:
    """The renderer ``reuse`` keeps for ``key`` (the Scene compared by identity, the rest by value),
    restarted; else a new one from ``build()``, kept in ``reuse``."""
    old = (reuse or {}).get("key")
    if reuse is not None and old is not None and old[0] is key[0] and old[1:] == key[1:]:
        r: Renderer = reuse["renderer"]
        r.restart()
        return r
    if reuse is not None:
        reuse.pop("renderer", None)  # let the old renderer's scene go before the new one is built
        reuse.pop("key", None)
    r = build()
    if reuse is not None:
        reuse.update(key=key, renderer=r)
    return r


def render_image(
    scene: Scene,
    *,
    width: int,
    height: int,
    spp: int,
    variant: str | None = None,
    reuse: dict[str, Any] | None = None,
) -> np.ndarray:
    """The beauty of frame 1 at ``width``×``height``×``spp`` as an (H, W, 3) linear array, no files, no blur.

    The same renderer, scene, materials, LODs and haze as :func:`render_scene`
    (``variant`` None: the same choice, :func:`choose_variant`); for callers
    that need the production image itself (look-dev's calibration, the job
    service's quick look).  ``reuse`` as in :func:`render_scene`.
    """
    chosen, _ = choose_variant(len(scene.instances), variant, scene.config.render.variant)
    size = FrameSize(int(width), int(height), int(spp), 1)
    r = _kept(reuse, (scene, chosen, size, False), lambda: make_renderer(scene, chosen, size))
    return np.asarray(r.frame(1.0).rgb, np.float64)[..., :3]


def _no_progress(_fraction: float, _message: str = "") -> None:
    """A progress callback that reports nothing."""


def render_scene(
    scene: Scene,
    *,
    output: str | Path,
    variant: str | None = None,
    frames: str | list[int] | None = None,
    preview: bool = False,
    progress: Callable[[float, str], None] | None = None,
    announce: Callable[[str, str], None] | None = None,
    on_pass: FramePassCallback | None = None,
    reuse: dict[str, Any] | None = None,
) -> RenderResult:
    """Render the scene's forest to ``output`` (EXR + PNG), a still or a frame sequence.

    ``frames``: None for a still at frame 1, a list of frame numbers or a spec
    like ``"1-120"``; with frames ``output`` is a pattern
    (``out/frame_####.exr``); a still written to a pattern is named as its frame 1.  ``progress(fraction, message)`` is called as
    passes finish, ``on_pass(frame, image so far, passes done, passes in the
    frame)`` with the frame's running image, ``announce(variant, reason)``
    once the variant is chosen.  ``reuse``: a dict the caller keeps between
    calls (the job service's workers); the renderer built for the same Scene
    object, variant, size and preview is kept in it and reused — terrain,
    materials and the Mitsuba scene of the last level-of-detail plan are not
    rebuilt, and the frames are the same bytes as a fresh render's.
    """
    config = scene.config
    if isinstance(frames, str):
        frames = parse_frames(frames)
    still = frames is None
    frame_list = [1] if frames is None else [int(f) for f in frames]
    if not frame_list:
        raise ParameterError("frames", "no frames to render")
    if still:  # a still to a pattern (f.%04d.exr) is frame 1 named by it
        targets = [output_paths(still_path(str(output)))]
    else:
        targets = [output_paths(frame_path(str(output), f)) for f in frame_list]
        if len({t[0] for t in targets}) != len(targets):
            raise ParameterError("output", f"{output}: every frame needs its own file; put #### in the name")
    inst = scene.instances
    chosen, reason = choose_variant(len(inst), variant, config.render.variant)
    if announce is not None:
        announce(chosen, reason)
    progress = progress or _no_progress
    progress(0.0, "building scene")
    size = frame_size(config, preview=preview)
    built = build_share(chosen, len(inst), size, len(frame_list))

    def building(fraction: float, step: str) -> None:
        progress(built * fraction, f"building scene: {step}")

    r = _kept(
        reuse,
        (scene, chosen, size, bool(preview)),
        lambda: make_renderer(scene, chosen, size, preview=preview, progress=building, frame=float(frame_list[0])),
    )
    n_sub = size.subframes
    per_frame = n_sub * len(r.passes(max(1, math.ceil(size.spp / n_sub))))
    total = len(frame_list) * per_frame
    written: list[Path] = []
    denoised = False

    for fi, (f, (exr, png)) in enumerate(zip(frame_list, targets)):

        def passed(img: Callable[[], np.ndarray], done: int, n: int, fi: int = fi, f: int = f) -> None:
            which = "" if still else f"frame {f} ({fi + 1}/{len(frame_list)}), "
            progress(built + (1.0 - built) * (fi * per_frame + done) / total, f"{which}pass {done}/{n}")
            if on_pass is not None:
                on_pass(f, img(), done, n)

        out = r.frame(float(f), passed)
        denoised |= out.denoised
        cam = out.camera
        rc = config.render
        stats = r.stats()
        attrs = {
            "forest:config": config.name,
            "forest:seed": int(config.seed),
            "forest:frame": int(f),
            "forest:variant": chosen,
            "forest:renderer": "forest_path"
            if not chosen.startswith("scalar")
            else "mitsuba " + ("volpath" if rc.alpha_shadows else "path"),
            "forest:spp": size.spp,
            "forest:subframes": n_sub,
            "forest:shutter": float(config.camera.shutter),
            "forest:max_depth": int(rc.max_depth),
            "forest:render_seed": int(rc.seed),
            "forest:preview": bool(preview),
            "forest:denoised": bool(out.denoised),
            "forest:leaf_model": r.leaf_model,
            "forest:trees": stats["trees"],
            "forest:instanced_triangles": stats["instanced_triangles"],
            "forest:unique_triangles": stats["unique_triangles"],
            "forest:shapegroups": stats["shapegroups"],
            "forest:lod": stats["lod"],
            "forest:lod_distances": ", ".join(f"{d:g}" for d in config.lod.bands),
            "forest:camera_position": ", ".join(f"{x:.4f}" for x in cam.position),
            "forest:camera_target": ", ".join(f"{x:.4f}" for x in cam.target),
            "forest:fov": float(cam.fov),
            "forest:wind_strength": float(config.wind.strength),
            "forest:haze": float(rc.haze),
            "forest:haze_height": float(rc.haze_height),
            "forest:sky": sky.kind if (sky := scene.lights.sky) is not None else "none",
        }
        if "samples_traced" in stats:  # mean samples per pixel traced (fewer than spp where adaptive sampling stopped)
            attrs["forest:samples_traced"] = float(stats["samples_traced"])  # type: ignore[arg-type]
        if scene.lod.mode != "distances":  # which rule chose the levels (forest:lod_distances says it for that one)
            attrs["forest:lod_rule"] = scene.lod.describe()
        if not chosen.startswith("scalar"):  # forest_path draws cut-out leaf cards solid on trees this small
            attrs["forest:solid_pixels"] = float(config.lod.solid_pixels)
        written += write_frame(
            exr,
            png,
            out,
            species_names=[str(n) for n in inst.species_names],
            near=float(config.camera.near),
            far=float(config.camera.far),
            view=rc.view,
            exposure=float(rc.exposure),
            look=rc.look,
            attributes=attrs,
            working_space=rc.working_space,
        )
    progress(1.0, "done")
    return RenderResult(
        paths=written,
        frames=frame_list,
        variant=chosen,
        variant_reason=reason,
        width=size.width,
        height=size.height,
        spp=size.spp,
        subframes=n_sub,
        trees=len(inst),
        instanced_triangles=r.max_instanced,
        unique_triangles=r.max_unique,
        shapegroups=r.max_groups,
        load_seconds=r.load_seconds,
        render_seconds=r.render_seconds,
        peak_memory_gb=peak_memory_gb(),
        gpu_peak_gb=gpu_peak_gb(chosen),
        lod_counts=r.lod_counts,
        lod_rule=scene.lod.describe()
        + (
            ""
            if chosen.startswith("scalar") or not config.lod.solid_pixels
            else f"; solid cards ≤ {config.lod.solid_pixels:g} px"
        ),
        denoised=denoised,
        denoise_rule="" if preview else denoise_rule(config.render.denoise, size.spp)[1],
        leaf_model=r.leaf_model,
    )
