"""``render_scene``: a Scene rendered with Mitsuba 3 — stills, fly-throughs, motion blur — to EXR + PNG.

The frames themselves are made by :class:`forest.render.frame.FrameRenderer`
(camera, levels of detail, sub-frames, sample passes, depth/id/species, haze);
the variant by :func:`forest.render.variant.choose_variant`.  Each frame is
written as a float EXR (beauty RGB plus ``depth``, ``id`` and ``species``
layers; settings and deterministic scene statistics in the header) and an
sRGB PNG beside it.
"""

from __future__ import annotations

import math
import resource
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..camera import frame_path, parse_frames
from ..errors import ParameterError
from ..images import write_image, write_multilayer_exr
from ..scene import Scene
from .frame import FrameRenderer, FrameSize
from .variant import choose_variant

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
    lod_counts: dict = field(default_factory=dict)
    denoised: bool = False
    leaf_model: str = ""

    def summary(self) -> str:
        """One line: trees, instanced and unique triangles, times, peak memory."""
        frames = f"{len(self.frames)} frames" if len(self.frames) > 1 else "1 frame"
        return (
            f"rendered {frames} {self.width}x{self.height} {self.spp} spp ({self.variant}): "
            f"{self.trees:,} trees, {self.instanced_triangles:,} instanced triangles, "
            f"{self.unique_triangles:,} unique, load {self.load_seconds:.1f} s, "
            f"render {self.render_seconds:.1f} s, peak {self.peak_memory_gb:.2f} GB"
        )


def peak_memory_gb() -> float:
    """Peak resident memory of this process (getrusage ru_maxrss, KiB on Linux)."""
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


def frame_size(config, *, preview: bool) -> FrameSize:
    """The render's size: ``[render]``, or the preview's (≤ 480 px wide, ≤ 8 spp, no motion blur)."""
    rc = config.render
    if preview:
        k = min(1.0, PREVIEW_WIDTH / rc.width)
        return FrameSize(max(1, round(rc.width * k)), max(1, round(rc.height * k)), min(rc.spp, PREVIEW_SPP), 1)
    return FrameSize(rc.width, rc.height, rc.spp, rc.subframes if config.camera.shutter > 0 else 1)


def _header_value(v):
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, np.integer)):
        return int(v) if -(2**31) <= int(v) < 2**31 else str(int(v))
    if isinstance(v, (float, np.floating)):
        return float(v)
    return str(v)


def _kept(reuse: dict[str, Any] | None, key: tuple[Any, ...], build: Callable[[], FrameRenderer]) -> FrameRenderer:
    """The renderer ``reuse`` keeps for ``key`` (the Scene compared by identity, the rest by value),
    restarted; else a new one from ``build()``, kept in ``reuse``."""
    old = (reuse or {}).get("key")
    if reuse is not None and old is not None and old[0] is key[0] and old[1:] == key[1:]:
        r: FrameRenderer = reuse["renderer"]
        r.restart()
        return r
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
    variant: str = "scalar_rgb",
    reuse: dict[str, Any] | None = None,
) -> np.ndarray:
    """The beauty of frame 1 at ``width``×``height``×``spp`` as an (H, W, 3) linear array, no files, no blur.

    The same scene, materials, LODs and haze as :func:`render_scene`; for
    callers that need the production image itself (look-dev's calibration, the
    job service's quick look).  ``reuse`` as in :func:`render_scene`.
    """
    size = FrameSize(int(width), int(height), int(spp), 1)
    r = _kept(reuse, (scene, variant, size, False), lambda: FrameRenderer(scene, variant, size))
    return np.asarray(r.frame(1.0)["rgb"], np.float64)[..., :3]


def render_scene(
    scene: Scene,
    *,
    output,
    variant: str | None = None,
    frames=None,
    preview: bool = False,
    progress: Callable[[float, str], None] | None = None,
    announce: Callable[[str, str], None] | None = None,
    on_pass: FramePassCallback | None = None,
    reuse: dict[str, Any] | None = None,
) -> RenderResult:
    """Render the scene's forest to ``output`` (EXR + PNG), a still or a frame sequence.

    ``frames``: None for a still at frame 1, a list of frame numbers or a spec
    like ``"1-120"``; with frames ``output`` is a pattern
    (``out/frame_####.exr``).  ``progress(fraction, message)`` is called as
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
    frame_list = [1] if still else [int(f) for f in frames]
    if not frame_list:
        raise ParameterError("frames", "no frames to render")
    if still:
        targets = [output_paths(output)]
    else:
        targets = [output_paths(frame_path(str(output), f)) for f in frame_list]
        if len({t[0] for t in targets}) != len(targets):
            raise ParameterError("output", f"{output}: every frame needs its own file; put #### in the name")
    inst = scene.instances
    chosen, reason = choose_variant(len(inst), variant, config.render.variant)
    if announce is not None:
        announce(chosen, reason)
    progress = progress or (lambda f, m="": None)
    progress(0.0, "building scene")
    size = frame_size(config, preview=preview)
    r = _kept(reuse, (scene, chosen, size, bool(preview)), lambda: FrameRenderer(scene, chosen, size, preview=preview))
    n_sub = size.subframes
    per_frame = n_sub * len(r.passes(max(1, math.ceil(size.spp / n_sub))))
    total = len(frame_list) * per_frame
    written: list[Path] = []
    denoised = False

    for fi, (f, (exr, png)) in enumerate(zip(frame_list, targets)):

        def passed(img: np.ndarray, done: int, n: int, fi: int = fi, f: int = f) -> None:
            progress((fi * per_frame + done) / total, f"frame {f} ({fi + 1}/{len(frame_list)})")
            if on_pass is not None:
                on_pass(f, img, done, n)

        out = r.frame(float(f), passed)
        denoised |= out["denoised"]
        g = r.graph
        cam = out["camera"]
        attrs = {
            "forest:config": config.name,
            "forest:seed": int(config.seed),
            "forest:frame": int(f),
            "forest:variant": chosen,
            "forest:spp": size.spp,
            "forest:subframes": n_sub,
            "forest:shutter": float(config.camera.shutter),
            "forest:max_depth": int(config.render.max_depth),
            "forest:render_seed": int(config.render.seed),
            "forest:preview": bool(preview),
            "forest:denoised": bool(out["denoised"]),
            "forest:leaf_model": r.materials.leaf_model,
            "forest:trees": g.trees,
            "forest:instanced_triangles": g.instanced_triangles,
            "forest:unique_triangles": g.unique_triangles,
            "forest:shapegroups": g.shapegroups,
            "forest:lod": ", ".join(f"{k}={v}" for k, v in g.lod_counts.items()),
            "forest:lod_distances": ", ".join(f"{d:g}" for d in config.lod.bands),
            "forest:camera_position": ", ".join(f"{x:.4f}" for x in cam.position),
            "forest:camera_target": ", ".join(f"{x:.4f}" for x in cam.target),
            "forest:fov": float(cam.fov),
            "forest:wind_strength": float(config.wind.strength),
            "forest:haze": float(config.render.haze),
            "forest:layers": "RGB beauty (linear); depth.Z distance to the first hit in metres (far clip where "
            "nothing is hit); id.Z tree id (-1 none); species.Z species index (-1 none)",
        }
        attrs = {k: _header_value(v) for k, v in attrs.items()}
        write_multilayer_exr(
            exr, {"": out["rgb"], "depth": out["depth"], "id": out["id"], "species": out["species"]}, attributes=attrs
        )
        write_image(png, out["rgb"])
        written += [exr, png]
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
        lod_counts=r.lod_counts,
        denoised=denoised,
        leaf_model=r.materials.leaf_model,
    )
