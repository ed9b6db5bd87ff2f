"""Running one task: the same public functions the CLI calls.

:func:`execute` is what every executor runs (in a local worker process or a Ray task).
A task spec is plain JSON::

    {"kind": "render" | "flythrough" | "match",
     "job_dir": "/data/jobs/<id>",          # the config's base folder, outputs go under out/
     "config": "<TOML text>", "overrides": {"render.width": 64, ...},
     "variant": "scalar_rgb" | null,
     "frames": [1, 2, 3] | null,            # fly-through frame range of this task
     "output": "out/render.exr",            # or "out/frame_####.exr"
     "match": {"reference": "photo.jpg", "iterations": 40, ...} | null}

``report(kind, payload)`` carries progress (``{"fraction", "message", "preview"}``) and
log lines back to the service.  The latest finished pass is copied to
``preview/task-<i>.png`` and named in the progress report so the page can show it:
each finished frame of a fly-through; for a still, first a quick look (the renderer's
fast ``preview`` mode, when the still asks for more than ``QUICK_LOOK_MIN_SPP``
samples), then the final image; for a match, the newest image look-dev wrote.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import math
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

Report = Callable[[str, dict], None]

PROGRESS_INTERVAL_S = 0.2
QUICK_LOOK_MIN_SPP = 8  # stills with more samples get a quick look first
QUICK_LOOK_SHARE = 0.1  # of the task's progress bar


def capabilities() -> dict[str, bool]:
    """Which job kinds this installation can run (the renderer and look-dev may be absent)."""

    def has(module: str, attr: str) -> bool:
        try:
            if importlib.util.find_spec(module) is None:
                return False
            return callable(getattr(importlib.import_module(module), attr, None))
        except Exception:
            return False

    render = has("forest.render", "render_scene")
    return {"render": render, "flythrough": render, "match": has("forest.lookdev", "match")}


class _Progress:
    """Throttled progress callback that also publishes the newest finished image as the preview."""

    def __init__(self, report: Report, job_dir: Path, task_index: int, watch: Path | None):
        self.report = report
        self.job_dir = job_dir
        self.task_index = task_index
        self.watch = watch
        self.last_sent = 0.0
        self.last_fraction = -1.0
        self.preview_src: tuple[str, float] | None = None
        self.preview_rel = f"preview/task-{task_index}.png"

    def _newest_png(self) -> Path | None:
        if self.watch is None or not self.watch.is_dir():
            return None
        best, best_t = None, -1.0
        for p in self.watch.glob("*.png"):
            if p.name.startswith("."):
                continue
            try:
                t = p.stat().st_mtime
            except OSError:
                continue
            if t > best_t:
                best, best_t = p, t
        return best

    def publish(self, image: Path) -> str | None:
        """Copy ``image`` to the task's preview file atomically; return its job-relative path."""
        dst = self.job_dir / self.preview_rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp = dst.with_name(f".{dst.name}.tmp")
        try:
            shutil.copyfile(image, tmp)
            tmp.replace(dst)
        except OSError:
            return None
        return self.preview_rel

    def check_preview(self) -> str | None:
        p = self._newest_png()
        if p is None:
            return None
        try:
            key = (p.name, p.stat().st_mtime)
        except OSError:
            return None
        if key == self.preview_src:
            return None
        self.preview_src = key
        return self.publish(p)

    def __call__(self, fraction: float, message: str = "") -> None:
        try:
            fraction = float(fraction)
        except (TypeError, ValueError):
            fraction = 0.0
        if not math.isfinite(fraction):
            fraction = 0.0
        now = time.monotonic()
        preview = self.check_preview()
        if preview is None and now - self.last_sent < PROGRESS_INTERVAL_S and fraction < 1.0:
            return
        self.last_sent = now
        self.last_fraction = fraction
        payload: dict[str, Any] = {"fraction": max(0.0, min(1.0, fraction)), "message": str(message)[:300]}
        if preview:
            payload["preview"] = preview
        self.report("progress", payload)


def _jsonable(value: Any, job_dir: Path) -> Any:
    """Render statistics as JSON: dataclasses → dicts, paths → job-relative strings."""
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
    try:
        import numpy as np

        if isinstance(value, np.generic):
            return _jsonable(value.item(), job_dir)
        if isinstance(value, np.ndarray):
            if value.size <= 64:
                return _jsonable(value.tolist(), job_dir)
            return {"array": list(value.shape), "dtype": str(value.dtype)}
    except ImportError:
        pass
    return str(value)


def _outputs(folder: Path, job_dir: Path, since: float) -> list[str]:
    """Files written under ``folder`` by this task (newer than ``since``), job-relative and sorted."""
    if not folder.is_dir():
        return []
    out = []
    for p in folder.rglob("*"):
        if p.is_file() and not p.name.startswith(".") and p.stat().st_mtime >= since - 1.0:
            out.append(p.relative_to(job_dir).as_posix())
    return sorted(out)


def execute(spec: dict, report: Report) -> dict:
    """Run one task; return ``{"outputs": [...], "stats": {...}}``.

    Raises :class:`forest.errors.ForestError` for user mistakes and lets other
    exceptions propagate (the worker turns both into a failed report).
    """
    from forest.config import parse_config
    from forest.errors import ForestError

    kind = spec["kind"]
    job_dir = Path(spec["job_dir"])
    job_dir.mkdir(parents=True, exist_ok=True)
    kept = job_dir / "config.toml"
    if not kept.exists():  # the job folder keeps the config it was rendered from
        from forest.atomic import atomic_path

        with atomic_path(kept) as tmp:
            tmp.write_text(spec["config"], encoding="utf-8")
    caps = capabilities()
    if not caps.get(kind):
        raise ForestError(f"{kind} jobs are not available in this installation")
    config = parse_config(spec["config"], base_dir=job_dir, overrides=spec.get("overrides") or None)
    started = time.time()
    if kind in ("render", "flythrough"):
        return _render(spec, config, job_dir, report, started)
    return _match(spec, config, job_dir, report, started)


def _render(spec: dict, config, job_dir: Path, report: Report, started: float) -> dict:
    from forest.render import render_scene

    output = job_dir / spec["output"]
    output.parent.mkdir(parents=True, exist_ok=True)
    index = int(spec.get("index", 0))
    progress = _Progress(report, job_dir, index, output.parent)
    frames = spec.get("frames")
    report(
        "log",
        {
            "line": f"render {'frames ' + _frames_text(frames) if frames else 'still'} "
            f"-> {spec['output']} (variant {spec.get('variant') or 'auto'})"
        },
    )
    from forest.scene import load_scene

    progress(0.0, "loading scene")
    scene = load_scene(config)
    if frames is None and not spec.get("preview") and config.render.spp > QUICK_LOOK_MIN_SPP:
        # A still: first a quick look (the renderer's fast preview), shown as the first pass.
        quick = job_dir / "preview" / "quick.exr"
        render_scene(
            scene,
            output=quick,
            variant=spec.get("variant"),
            preview=True,
            progress=lambda f, m="": progress(QUICK_LOOK_SHARE * float(f), f"quick look: {m}"),
        )
        shown = progress.publish(quick.with_suffix(".png"))
        if shown:
            report("progress", {"fraction": QUICK_LOOK_SHARE, "message": "quick look ready", "preview": shown})

        def main_progress(f: float, m: str = "") -> None:
            progress(QUICK_LOOK_SHARE + (1.0 - QUICK_LOOK_SHARE) * float(f), m)
    else:
        main_progress = progress
    result = render_scene(
        scene,
        output=output,
        variant=spec.get("variant"),
        frames=frames,
        preview=bool(spec.get("preview", False)),
        progress=main_progress,
    )
    paths = getattr(result, "paths", None)
    if paths:
        outs = sorted(_jsonable(Path(p), job_dir) for p in paths)
    else:
        outs = _outputs(output.parent, job_dir, started)
    pngs = [o for o in outs if o.endswith(".png")]
    final = progress.publish(job_dir / pngs[-1]) if pngs else None
    payload = {"fraction": 1.0, "message": "done"}
    if final:
        payload["preview"] = final
    report("progress", payload)
    return {"outputs": outs, "stats": _jsonable(result, job_dir), "preview": final}


def _frames_text(frames: list[int]) -> str:
    return f"{frames[0]}-{frames[-1]}" if len(frames) > 1 else str(frames[0])


def _match(spec: dict, config, job_dir: Path, report: Report, started: float) -> dict:
    from forest import lookdev

    m = dict(spec.get("match") or {})
    out_dir = job_dir / "out"
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = _Progress(report, job_dir, int(spec.get("index", 0)), out_dir)
    reference = job_dir / m.pop("reference")
    kwargs = {k: v for k, v in m.items() if v is not None}
    if spec.get("variant"):
        kwargs["variant"] = spec["variant"]
    report("log", {"line": f"match {reference.name} -> out/ ({kwargs})"})
    from forest.scene import load_scene

    progress(0.0, "loading scene")
    scene = load_scene(config)
    progress(0.0, "building proxy")
    result = lookdev.match(scene, reference, out_dir, progress=progress, **kwargs)
    outs = _outputs(out_dir, job_dir, started)
    pngs = [o for o in outs if o.endswith(".png")]
    payload = {"fraction": 1.0, "message": "done"}
    final = progress.publish(job_dir / pngs[-1]) if pngs else None
    if final:
        payload["preview"] = final
    report("progress", payload)
    return {"outputs": outs, "stats": _jsonable(result, job_dir), "preview": final}
