"""Running one task: the same public functions the CLI calls, with live reports.

:func:`execute` is what every worker runs — a local worker process
(:mod:`forest.service.worker`) or a Ray actor (:mod:`forest.service.executors.ray`).
It takes a :class:`~forest.service.models.TaskSpec` and a :class:`TaskContext` (where
to write, where the inputs are, the worker's scene cache, how to report) and returns a
:class:`~forest.service.models.TaskResult`.

Frame tasks (stills and fly-throughs) render frame by frame with
``forest.render.render_scene(frames=[f], reuse=…, on_pass=…)``:

* once the scene is loaded, the whole render's memory is checked as ``forest render`` checks
  it (:func:`_check_memory`: the trees and the level-of-detail plan known, against this
  worker's room); a render that will not fit fails with the CLI's one line, before any output;
* a frame whose EXR and PNG are already in the job folder (or that the service says it
  holds, ``spec.skip_frames``) is not rendered again: it is reported ``resumed``;
* after every sample pass the image so far is published as the task's preview
  (``preview/task-<i>.png``, at most every ``PREVIEW_INTERVAL_S``, always the last;
  once the task is done its last frame's PNG takes that place), through the scene's
  view transform and exposure (``[render] view``, ``exposure``) as the final PNG is;
  a still first shows a *quick look* — the same scene at a fraction of the size with
  one sample per pixel — so the first pixels appear before the first full pass;
* each finished frame gets a thumbnail (``thumbs/frame_NNNN.png``) and a ``frame`` report;
* progress is the share of the task's passes done, and the ETA comes from the measured
  pass times: with *p* the mean time of a pass in the current frame (passes after the
  first; the first also pays the scene's build), *r* its passes left, *F* the mean time
  of the task's finished frames and *n* the frames after the current one,
  ETA = p·r + F·n (before a frame has finished, F is estimated by the current frame's
  elapsed time plus p·r).

Match tasks call ``forest.lookdev.match`` and publish the newest image it writes; export
tasks call ``forest.export.rib.export_rib`` / ``forest.export.usd.export_usd``.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .models import FRAME_KINDS, FrameDone, Log, Progress, TaskResult, TaskSpec
from .scenecache import LoadedScene, SceneCache
from .transfer import read_files

PREVIEW_INTERVAL_S = 0.25
PROGRESS_INTERVAL_S = 0.2
#: Longest side of a published preview image and of a frame's thumbnail, in pixels.
PREVIEW_MAX = 1024
THUMB_MAX = 192
#: A still gets a quick look when its first pass costs more than this many quick looks, and
#: its forest is small enough that a second renderer's build (≈ 2 s and 0.6 GB at 100 000
#: trees in scalar_rgb) is cheap beside that pass.
QUICK_LOOK_RATIO = 8.0
QUICK_LOOK_WIDTH = 160
QUICK_LOOK_MAX_TREES = 100_000
EXPORT_KINDS = ("rib", "usd")


def capabilities() -> dict[str, bool]:
    """Which job kinds this installation can run (the renderer, look-dev or USD may be absent)."""

    def has(module: str, attr: str) -> bool:
        try:
            if importlib.util.find_spec(module) is None:
                return False
            return callable(getattr(importlib.import_module(module), attr, None))
        except Exception:
            return False

    render = has("forest.render", "render_scene")
    rib = has("forest.export.rib", "export_rib")
    usd = rib and importlib.util.find_spec("pxr") is not None
    return {"render": render, "flythrough": render, "match": has("forest.lookdev", "match"), "rib": rib, "usd": usd}


@dataclass
class TaskContext:
    """Where one attempt runs and how it reports.

    ``job_dir``: the folder outputs are written to (the service's job folder when the
    worker shares its disk, else the worker's own copy); ``inputs()``: a folder holding
    the task's inputs under their job-relative names; ``ship``: attach written files
    to the reports (the service does not see ``job_dir``).
    """

    task_id: int
    attempt: int
    job_dir: Path
    inputs: Callable[[], Path]
    cache: SceneCache
    emit: Callable[[Any], None]
    ship: bool = False
    _last_progress: float = field(default=0.0, repr=False)

    def send(self, cls: type, files: list[str] | None = None, **fields: Any) -> None:
        """Emit a report of type ``cls`` for this attempt, with ``files`` (job-relative) attached when shipping."""
        shipped = read_files(self.job_dir, files) if self.ship and files else {}
        self.emit(cls(task_id=self.task_id, attempt=self.attempt, files=shipped, **fields))

    def log(self, line: str) -> None:
        """Send one line for the task's log."""
        self.send(Log, line=line)

    def progress(self, fraction: float, message: str, *, force: bool = False, **fields: Any) -> None:
        """A throttled progress report (``force`` or a preview always goes)."""
        now = time.monotonic()
        if not force and fields.get("preview") is None and now - self._last_progress < PROGRESS_INTERVAL_S:
            return
        self._last_progress = now
        fraction = float(fraction) if math.isfinite(float(fraction)) else 0.0
        preview = fields.get("preview")
        self.send(
            Progress,
            files=[preview] if preview else None,
            fraction=max(0.0, min(1.0, fraction)),
            message=str(message)[:300],
            **fields,
        )


def execute(spec: TaskSpec, ctx: TaskContext) -> TaskResult:
    """Run one task; raise :class:`forest.errors.ForestError` for a mistake in the job."""
    from forest.errors import ForestError

    if not capabilities().get(spec.kind):
        raise ForestError(f"kind: {spec.kind} jobs are not available on this worker")
    ctx.job_dir.mkdir(parents=True, exist_ok=True)
    if spec.kind in FRAME_KINDS:
        return _render(spec, ctx)
    if spec.kind == "match":
        return _match(spec, ctx)
    return _export(spec, ctx)


def _load(spec: TaskSpec, ctx: TaskContext) -> LoadedScene:
    ctx.progress(0.0, "loading scene", force=True)
    scene, hit = ctx.cache.get(spec, ctx.inputs())
    how = "cached" if hit else f"loaded in {scene.load_seconds:.2f} s" + ("" if scene.scattered else " (trees cached)")
    ctx.log(f"scene {spec.scene_key[:12]} {how}: {len(scene.instances):,} trees")
    ctx.progress(0.0, f"scene {'cached' if hit else 'loaded'}", force=True, trees=len(scene.instances))
    return scene


# -- images -----------------------------------------------------------------------------


def _fit(rgb: np.ndarray, longest: int) -> np.ndarray:
    from forest.images import resample

    h, w = rgb.shape[:2]
    k = longest / max(h, w)
    if k >= 1.0:
        return rgb
    return resample(rgb, max(1, round(h * k)), max(1, round(w * k)))


def _publish(ctx: TaskContext, rel: str, rgb: np.ndarray, longest: int, config: Any) -> str:
    """Write a scene-linear image at ``rel`` in the job folder (atomically) as the final PNG will look: through the
    config's view transform, exposure and look (``[render] view``, ``exposure``, ``look``; :func:`forest.imaging.write_display`)."""
    from forest.imaging import write_display

    r = config.render
    write_display(
        ctx.job_dir / rel,
        _fit(np.asarray(rgb, np.float32)[..., :3], longest),
        view=r.view,
        exposure=float(r.exposure),
        look=r.look,
    )
    return rel


def _thumbnail(ctx: TaskContext, png: str, frame: int) -> str | None:
    from forest.images import read_image, srgb_to_linear, write_image

    src = ctx.job_dir / png
    if not src.is_file():
        return None
    rel = f"thumbs/frame_{frame:04d}.png"
    rgb = srgb_to_linear(read_image(src)[..., :3])
    write_image(ctx.job_dir / rel, _fit(rgb, THUMB_MAX))
    return rel


# -- frames -----------------------------------------------------------------------------


def frame_files(spec: TaskSpec, frame: int) -> tuple[str, str]:
    """Job-relative EXR and PNG of a frame (a still has one, named by ``spec.output``)."""
    from forest.frames import frame_path

    exr = spec.output if spec.kind == "render" else frame_path(spec.output, frame)
    return exr, str(Path(exr).with_suffix(".png").as_posix())


class _Clock:
    """Pass and frame times of one task, and the ETA they give (see the module docstring)."""

    def __init__(self, frames_left: int):
        self.frames_left = frames_left  # frames still to render, the current one included
        self.frame_times: list[float] = []
        self.frame_start = time.monotonic()
        self.pass_times: list[float] = []
        self.last_pass = self.frame_start

    def start_frame(self) -> None:
        self.frame_start = self.last_pass = time.monotonic()
        self.pass_times = []

    def passed(self) -> None:
        now = time.monotonic()
        self.pass_times.append(now - self.last_pass)
        self.last_pass = now

    def end_frame(self) -> float:
        seconds = time.monotonic() - self.frame_start
        self.frame_times.append(seconds)
        self.frames_left -= 1
        return seconds

    def eta(self, done: int, total: int) -> float | None:
        if not self.pass_times:
            return None
        steady = self.pass_times[1:] or self.pass_times
        left_here = (sum(steady) / len(steady)) * max(0, total - done)
        if self.frame_times:
            per_frame = sum(self.frame_times) / len(self.frame_times)
        else:
            per_frame = (time.monotonic() - self.frame_start) + left_here
        return left_here + per_frame * max(0, self.frames_left - 1)


def _render(spec: TaskSpec, ctx: TaskContext) -> TaskResult:
    from forest.render import render_scene

    still = spec.kind == "render"
    frames = list(spec.frames or (1,))
    skip = set(spec.skip_frames)
    on_disk = [f for f in frames if f in skip or all((ctx.job_dir / p).is_file() for p in frame_files(spec, f))]
    todo = [f for f in frames if f not in on_disk]
    n = len(frames)
    finished = 0
    outputs: list[str] = []
    thumbs: dict[int, str] = {}
    for f in on_disk:
        exr, png = frame_files(spec, f)
        thumb = f"thumbs/frame_{f:04d}.png"
        if not (ctx.job_dir / thumb).is_file() and (ctx.job_dir / png).is_file():
            thumb = _thumbnail(ctx, png, f) or thumb  # it died between the frame and its thumbnail
        finished += 1
        outputs += [exr, png, thumb]
        thumbs[f] = thumb
        ctx.send(FrameDone, frame=f, outputs=[exr, png], thumb=thumb, resumed=True)
    if on_disk:
        ctx.log(f"frames on disk, not rendered again: {_ranges(on_disk)}")
    if not todo:
        ctx.progress(1.0, "all frames were on disk", force=True)
        return TaskResult(outputs=sorted(set(outputs)), resumed_frames=on_disk, preview=_last(thumbs))

    scene = _load(spec, ctx)
    _check_memory(spec, ctx, scene, todo)
    preview_rel = f"preview/task-{spec.index}.png"
    clock = _Clock(len(todo))
    if still and spec.quick_look and spec.variant in (None, "scalar_rgb"):
        _quick_look(spec, ctx, scene, preview_rel)
    last_preview = [0.0]
    stats: list[Any] = []
    render_seconds = 0.0
    said: set[str] = set()

    def announce(variant: str, reason: str) -> None:
        """The variant and why, once per task (a failed GPU self-check says so here)."""
        line = f"variant: {variant} ({reason})"
        if line not in said:
            said.add(line)
            ctx.log(line)

    for f in todo:
        exr, png = frame_files(spec, f)
        clock.start_frame()
        label = "still" if still else (f"frame {f}" if n == 1 else f"frame {f} ({finished + 1}/{n})")

        def on_pass(
            frame: int, rgb: np.ndarray, done: int, total: int, label: str = label, base: int = finished
        ) -> None:
            clock.passed()
            now = time.monotonic()
            fraction = (base + done / max(1, total)) / n
            fields: dict[str, Any] = {
                "frame": frame,
                "passes_done": done,
                "passes_total": total,
                "eta_s": clock.eta(done, total),
            }
            if done == total or now - last_preview[0] >= PREVIEW_INTERVAL_S:
                last_preview[0] = now
                fields["preview"] = _publish(ctx, preview_rel, rgb, PREVIEW_MAX, scene.config)
            ctx.progress(fraction, f"{label}: pass {done}/{total}", force=True, **fields)

        def progress(_fraction: float, message: str = "", label: str = label, base: int = finished, f: int = f) -> None:
            if message == "building scene":
                ctx.progress(base / n, f"{label}: building scene", force=True, frame=f)

        result = render_scene(
            scene.scene,
            output=ctx.job_dir / spec.output,
            variant=spec.variant,
            frames=None if still else [f],
            preview=spec.preview,
            progress=progress,
            on_pass=on_pass,
            reuse=scene.reuse,
            announce=announce,
        )
        seconds = clock.end_frame()
        render_seconds += result.render_seconds
        stats.append(result)
        finished += 1
        made = _thumbnail(ctx, png, f)
        if made:
            thumbs[f] = made
        outputs += [exr, png] + ([made] if made else [])
        ctx.send(
            FrameDone,
            files=[exr, png] + ([made] if made else []),
            frame=f,
            seconds=seconds,
            outputs=[exr, png],
            thumb=made,
        )
        ctx.log(f"{label} rendered in {seconds:.2f} s ({result.variant}, {result.trees:,} trees)")
    # the finished frame is the task's image now: its pass preview goes (one file per task
    # would otherwise stay for every frame of a long fly-through)
    final = frame_files(spec, todo[-1])[1]
    (ctx.job_dir / preview_rel).unlink(missing_ok=True)
    ctx.progress(1.0, "done", force=True, preview=final, eta_s=0.0)
    summary = _jsonable(stats[-1], ctx.job_dir)
    summary["frames"] = todo
    summary["render_seconds"] = round(render_seconds, 3)
    summary.pop("paths", None)
    return TaskResult(
        outputs=sorted(set(outputs)),
        stats=summary,
        preview=final,
        trees=len(scene.instances),
        resumed_frames=on_disk,
    )


def _check_memory(spec: TaskSpec, ctx: TaskContext, scene: LoadedScene, frames: list[int]) -> None:
    """Refuse the render before it starts when it will not fit, as ``forest render`` does once its scene is loaded.

    The CLI's estimate with the trees known (:func:`forest.preflight.render_estimate`: the frame's size, the
    trees, the species' triangles and, in the JIT variants, the trees the level-of-detail plan merges at the far
    level in ``frames``, :func:`forest.render.path.from_scene.far_plan`) against the smaller of this worker's
    room (:func:`forest.preflight.memory_room`: available memory and its cgroups' limits) and the room the
    service states (``spec.memory_bytes``).  Too big: a one-line :class:`~forest.errors.ForestError` in the
    request's words (:func:`forest.service.jobs.memory_line`), rather than a worker killed for memory; else the
    estimate goes to the task's log.
    """
    from forest import preflight
    from forest.errors import ConfigError, ForestError
    from forest.memory import Room
    from forest.render import choose_variant
    from forest.render.render import frame_size

    from .jobs import memory_line

    room = preflight.memory_room()
    if spec.memory_bytes is not None and (room is None or spec.memory_bytes < room.bytes):
        room = Room(spec.memory_bytes)
    if room is None:
        return
    cfg, trees = scene.config, len(scene.instances)
    size = frame_size(cfg, preview=spec.preview)
    variant, _reason = choose_variant(trees, spec.variant, cfg.render.variant)
    estimate = preflight.scene_render_estimate(scene.scene, variant, [float(f) for f in frames], size)
    try:
        preflight.check_render_memory(cfg, estimate, available=room)
    except ConfigError as e:
        raise ForestError(memory_line(e, spec.overrides)) from None
    ctx.log(f"render: {estimate.line(room)}")


def _quick_look(spec: TaskSpec, ctx: TaskContext, scene: LoadedScene, rel: str) -> None:
    """The still at ``QUICK_LOOK_WIDTH`` pixels and 1 sample, when its first pass is much dearer."""
    from forest.render.frame import SCALAR_PASS_SPP
    from forest.render.render import PREVIEW_SPP, PREVIEW_WIDTH, render_image

    rc = scene.config.render
    width, height, spp = rc.width, rc.height, rc.spp
    if spec.preview:
        k = min(1.0, PREVIEW_WIDTH / width)
        width, height, spp = max(1, round(width * k)), max(1, round(height * k)), min(spp, PREVIEW_SPP)
    first_pass = width * height * min(spp, SCALAR_PASS_SPP)
    qw = min(QUICK_LOOK_WIDTH, width)
    qh = max(1, round(height * qw / width))
    if first_pass < QUICK_LOOK_RATIO * qw * qh or len(scene.instances) > QUICK_LOOK_MAX_TREES:
        return
    t0 = time.monotonic()
    rgb = render_image(scene.scene, width=qw, height=qh, spp=1, reuse=scene.quick)
    ctx.progress(0.0, "quick look", force=True, preview=_publish(ctx, rel, rgb, PREVIEW_MAX, scene.config), frame=1)
    ctx.log(f"quick look {qw}x{qh} in {time.monotonic() - t0:.2f} s")


def _publish_file(ctx: TaskContext, rel: str, png: str) -> str | None:
    """Copy a finished PNG to the preview file (atomically)."""
    import shutil

    from forest.atomic import atomic_path

    src = ctx.job_dir / png
    if not src.is_file():
        return None
    with atomic_path(ctx.job_dir / rel) as tmp:
        shutil.copyfile(src, tmp)
    return rel


def _last(thumbs: dict[int, str]) -> str | None:
    return thumbs[max(thumbs)] if thumbs else None


def _ranges(frames: list[int]) -> str:
    out: list[str] = []
    start = prev = frames[0]
    for f in [*frames[1:], None]:
        if f is not None and f == prev + 1:
            prev = f
            continue
        out.append(str(start) if start == prev else f"{start}-{prev}")
        if f is not None:
            start = prev = f
    return ",".join(out)


# -- match and exports --------------------------------------------------------------------


def _newest_png(folder: Path) -> Path | None:
    pngs = [p for p in folder.glob("*.png") if not p.name.startswith(".")] if folder.is_dir() else []
    return max(pngs, key=lambda p: p.stat().st_mtime) if pngs else None


def _outputs(ctx: TaskContext, folder: Path) -> list[str]:
    return sorted(
        p.relative_to(ctx.job_dir).as_posix() for p in folder.rglob("*") if p.is_file() and not p.name.startswith(".")
    )


def _match(spec: TaskSpec, ctx: TaskContext) -> TaskResult:
    from forest import lookdev

    assert spec.match is not None
    scene = _load(spec, ctx)
    out_dir = ctx.job_dir / spec.output
    out_dir.mkdir(parents=True, exist_ok=True)
    reference = ctx.inputs() / spec.match.reference
    kwargs = {
        k: v
        for k, v in spec.match.model_dump().items()
        if k != "reference" and v is not None and not (k == "params" and not v)
    }
    if spec.variant:
        kwargs["variant"] = spec.variant
    ctx.log(f"match {spec.match.reference} -> {spec.output}/ ({kwargs})")
    preview_rel = f"preview/task-{spec.index}.png"
    shown: list[tuple[str, float] | None] = [None]

    def progress(fraction: float, message: str = "") -> None:
        fields: dict[str, Any] = {}
        newest = _newest_png(out_dir)
        if newest is not None and (newest.name, newest.stat().st_mtime) != shown[0]:
            shown[0] = (newest.name, newest.stat().st_mtime)
            fields["preview"] = _publish_file(ctx, preview_rel, newest.relative_to(ctx.job_dir).as_posix())
        ctx.progress(fraction, message, **fields)

    result = lookdev.match(scene.scene, reference, out_dir, progress=progress, **kwargs)
    outs = _outputs(ctx, out_dir)
    newest = _newest_png(out_dir)
    final = _publish_file(ctx, preview_rel, newest.relative_to(ctx.job_dir).as_posix()) if newest else None
    ctx.send(Log, files=outs, line=f"match wrote {len(outs)} files")
    ctx.progress(1.0, "done", force=True, preview=final, eta_s=0.0)
    return TaskResult(outputs=outs, stats=_jsonable(result, ctx.job_dir), preview=final, trees=len(scene.instances))


def _export(spec: TaskSpec, ctx: TaskContext) -> TaskResult:
    scene = _load(spec, ctx)
    target = ctx.job_dir / spec.output
    frames = list(spec.frames) if spec.frames else None

    def progress(fraction: float, message: str = "") -> None:
        ctx.progress(fraction, message)

    if spec.kind == "rib":
        from forest.export.rib import export_rib

        result: Any = export_rib(scene.scene, target, renderman22=spec.renderman22, frames=frames, progress=progress)
        folder = target
    else:
        from forest.export.usd import export_usd

        result = export_usd(scene.scene, target, frames=frames, progress=progress)
        folder = target.parent
    outs = _outputs(ctx, folder)
    ctx.send(Log, files=outs, line=f"{spec.kind} export wrote {len(outs)} files")
    ctx.progress(1.0, "done", force=True, eta_s=0.0)
    return TaskResult(outputs=outs, stats=_jsonable(result, ctx.job_dir), trees=len(scene.instances))


def _jsonable(value: Any, job_dir: Path) -> Any:
    """Statistics as JSON: dataclasses → dicts, paths → job-relative strings, arrays summarised."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name), job_dir) for f in dataclasses.fields(value)}
    if isinstance(value, Path):
        try:
            return value.resolve().relative_to(job_dir.resolve()).as_posix()
        except ValueError:
            return value.name
    if isinstance(value, dict):
        return {str(k): _jsonable(v, job_dir) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v, job_dir) for v in value]
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.generic):
        return _jsonable(value.item(), job_dir)
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist(), job_dir) if value.size <= 64 else {"array": list(value.shape)}
    return str(value)
