"""What the API and the page show of a job: views built from the store's rows.

Times are epoch seconds.  ``elapsed_s`` runs from the job's start to its end (or now).
The job's ETA combines the tasks' own estimates (from their measured pass times, see
:mod:`forest.service.runner`) with the mean time of the job's finished tasks::

    ETA = (Σ_running eta_i + queued · T̄) / max(1, running)

where T̄ is the mean time of its succeeded tasks, or while none has finished, the mean
estimated total (elapsed + eta) of the running ones.
"""

from __future__ import annotations

import time
from typing import Any

from .models import FRAME_KINDS

FIELDS = {
    "frames": "settings.frames",
    "variant": "settings.variant",
    "lookdev.iterations": "settings.iterations",
    "lookdev.resolution": "settings.resolution",
    "lookdev.params": "settings.params",
    "lookdev.mode": "settings.mode",
    "lookdev.spp": "settings.match_spp",
    "lookdev.variant": "settings.variant",
    "reference": "settings.reference",
}
#: Library parameters whose JSON field differs by job kind.
KIND_FIELDS: dict[tuple[str, str], str] = {}


def field_name(param: str, kind: str | None = None) -> str:
    """The request's JSON field for a library parameter (``frames`` → ``settings.frames``)."""
    return KIND_FIELDS.get((kind or "", param)) or FIELDS.get(param) or f"settings.{param}"


def _links(jid: str) -> dict[str, str]:
    base = f"/jobs/{jid}"
    return {
        "self": base,
        "events": f"{base}/events",
        "cancel": f"{base}/cancel",
        "resume": f"{base}/resume",
        "log": f"{base}/log",
        "result": f"{base}/result",
        "frames": f"{base}/frames",
        "download": f"{base}/outputs.zip",
    }


def task_view(job_id: str, t: dict, frames_done: list[int], now: float) -> dict:
    """A task as :class:`~forest.service.api.schemas.TaskView` shows it; ``seconds`` counts up while it runs."""
    started, finished = t.get("started"), t.get("finished")
    if t["state"] == "running" and started:
        seconds = now - started
    elif t.get("seconds") is not None:
        seconds = t["seconds"]
    else:
        seconds = None
    return {
        "index": t["idx"],
        "state": t["state"],
        "attempt": t["attempt"],
        "max_attempts": t["max_attempts"],
        "progress": min(1.0, max(0.0, float(t["progress"] or 0.0))),
        "message": t["message"],
        "frames": t["frames"],
        "frames_done": frames_done,
        "frame": t.get("frame"),
        "passes_done": t.get("passes_done"),
        "passes_total": t.get("passes_total"),
        "started": started,
        "finished": finished,
        "seconds": round(seconds, 3) if seconds is not None else None,
        "eta_s": t.get("eta_s") if t["state"] == "running" else None,
        "worker": t["worker"],
        "error": t["error"],
        "log": f"/jobs/{job_id}/tasks/{t['idx']}/log",
        "preview": f"/jobs/{job_id}/files/{t['preview']}" if t.get("preview") else None,
    }


def job_eta(tasks: list[dict], now: float) -> float | None:
    """Seconds until the job's tasks finish: the running tasks' estimates plus the queued ones at the mean task time,
    over the tasks running at once; 0 when none is left, None while an estimate is missing.
    """
    running = [t for t in tasks if t["state"] == "running"]
    queued = sum(t["state"] == "queued" for t in tasks)
    if not running and not queued:
        return 0.0 if tasks else None
    done = [t["seconds"] for t in tasks if t["state"] == "succeeded" and t.get("seconds") is not None]
    if done:
        mean = sum(done) / len(done)
    else:
        est = [now - t["started"] + t["eta_s"] for t in running if t.get("eta_s") is not None and t.get("started")]
        mean = sum(est) / len(est) if est else None
    ahead = [t["eta_s"] for t in running if t.get("eta_s") is not None]
    if len(ahead) < len(running) or (queued and mean is None):
        return None
    return (sum(ahead) + queued * (mean or 0.0)) / max(1, len(running))


def job_view(job: dict, *, tasks: bool = False, frames: list[dict] | None = None, now: float | None = None) -> dict:
    """A job as ``GET /jobs/{id}`` shows it (``tasks``: with its tasks; needs ``job["tasks"]``)."""
    now = time.time() if now is None else now
    jid = job["id"]
    v: dict[str, Any] = {
        k: job[k]
        for k in (
            "id",
            "kind",
            "state",
            "priority",
            "message",
            "error",
            "created",
            "started",
            "finished",
            "cancel_requested",
            "settings",
        )
    }
    v["name"] = job.get("name")
    v["progress"] = min(1.0, max(0.0, float(job["progress"] or 0.0)))
    v["trees"] = job.get("trees")
    v["frames_total"] = job.get("frames_total") or 0
    v["frames_done"] = job.get("frames_done") or 0
    v["outputs_deleted"] = bool(job.get("outputs_deleted"))
    v["archived"] = bool(job.get("archived"))
    started = job.get("started")
    v["elapsed_s"] = round((job.get("finished") or now) - started, 3) if started else None
    preview = job.get("preview")
    v["preview"] = f"/jobs/{jid}/files/{preview}?v={int(v['progress'] * 1000)}-{job['state']}" if preview else None
    v["links"] = _links(jid)
    v["eta_s"] = None
    if "tasks" in job:
        v["eta_s"] = job_eta(job["tasks"], now)
        if tasks:
            by_task: dict[int, list[int]] = {}
            for f in frames or []:
                by_task.setdefault(f["task_idx"], []).append(f["frame"])
            v["tasks"] = [task_view(jid, t, by_task.get(t["idx"], []), now) for t in job["tasks"]]
    if v["eta_s"] is not None:
        v["eta_s"] = round(v["eta_s"], 1)
    return v


def frame_views(job: dict, frames: list[dict]) -> list[dict]:
    """Every frame of a frame job, in order, with its state and files (``job["tasks"]`` needed)."""
    if job["kind"] not in FRAME_KINDS:
        return []
    jid = job["id"]
    done = {f["frame"]: f for f in frames}
    out = []
    for t in job["tasks"]:
        for frame in t["frames"] or (1,):
            rec = done.get(frame)
            if rec is not None:
                state = "done"
            elif t["state"] == "running":
                state = "rendering" if t.get("frame") == frame else "queued"
            elif t["state"] == "succeeded":
                state = "done"
            else:
                state = t["state"]
            files = {}
            if rec is not None and not job.get("outputs_deleted"):
                for rel in rec["outputs"]:
                    files[rel.rsplit(".", 1)[-1]] = f"/jobs/{jid}/files/{rel}"
            preview = f"/jobs/{jid}/files/{t['preview']}" if state == "rendering" and t.get("preview") else None
            out.append(
                {
                    "frame": frame,
                    "task": t["idx"],
                    "state": state,
                    "attempt": rec["attempt"] if rec else t["attempt"],
                    "seconds": round(rec["seconds"], 3) if rec else None,
                    "resumed": bool(rec["resumed"]) if rec else False,
                    "thumb": f"/jobs/{jid}/files/{rec['thumb']}" if rec and rec.get("thumb") else None,
                    "preview": preview,
                    "exr": files.get("exr"),
                    "png": files.get("png"),
                    "error": t["error"] if state == "failed" else None,
                }
            )
    return out
