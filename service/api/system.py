"""The service itself: ``GET /health``, ``GET /workers`` (what each runs), ``GET /examples``."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from ..assets import check_memory_limit
from ..store import JOB_STATES
from .deps import Service, service
from .schemas import Example, Health, LimitsView, WorkerList

router = APIRouter()


@router.get("/health", response_model=Health, summary="Liveness and queue counts")
def health(svc: Service = Depends(service)) -> dict:
    """``ok`` with the executor, worker count, jobs per state, the capabilities, the limits on what a job may ask
    for (``forest serve --max-…``; the page's inputs follow them) with an upload's decode budget and the memory
    its checks use, and the open event streams."""
    counts = svc.db.counts()
    counts["total"] = sum(counts[s] for s in JOB_STATES)
    return {
        "status": "ok",
        "executor": svc.executor.name if svc.executor else "none",
        "workers": svc.config.workers,
        "counts": counts,
        "capabilities": svc.caps,
        "requeued_at_start": svc.db.requeued_on_open,
        "streams": svc.notifier.subscribers(),
        "limits": limits_view(svc),
    }


def limits_view(svc: Service) -> dict:
    """The service's limits as :class:`~.schemas.LimitsView` shows them: the :class:`~..jobs.Limits` fields, the
    upload check's address space (:func:`~..assets.check_memory_limit`) and the render memory room that
    submission checks against (:func:`worker_room`)."""
    limits = svc.config.limits
    shown = {name: getattr(limits, name) for name in LimitsView.model_fields if hasattr(limits, name)}
    shown["max_check_memory_bytes"] = check_memory_limit(limits.max_decoded_bytes)
    shown["worker_memory_bytes"] = worker_room(svc)
    return shown


def worker_room(svc: Service) -> int | None:
    """The bytes a render job's image must fit at submission, as :func:`~..jobs.prepare` reads them: the stated
    ``Limits.worker_memory_bytes``, else for local workers this machine's room
    (:func:`forest.preflight.available_memory`); None where submission does not check (or the room is unknown)."""
    from forest import preflight
    from forest.errors import ForestError

    limits = svc.config.limits
    if not limits.check_memory:
        return None
    if limits.worker_memory_bytes is not None:
        return limits.worker_memory_bytes
    if svc.config.executor != "local":
        return None
    try:
        return preflight.available_memory()
    except ForestError:  # a bad $FOREST_MEMORY_GB: submission says so, /health stays up
        return None


@router.get("/workers", response_model=WorkerList, summary="Worker slots and what each runs")
def workers(svc: Service = Depends(service)) -> dict:
    """Each worker slot and, when busy, the job, task, frame and progress it runs."""
    if svc.executor is None:
        return {"workers": []}
    out = []
    for w in svc.executor.workers():
        if w.job_id is not None and w.task is not None:
            job = svc.db.get_job(w.job_id)
            task = svc.db.get_task(w.job_id, w.task)
            w = w.model_copy(
                update={
                    "job_name": job.get("name") if job else None,
                    "frame": task.get("frame") if task else None,
                    "progress": task.get("progress") if task else None,
                }
            )
        out.append(w.model_dump())
    return {"workers": out}


@router.get("/examples", response_model=list[Example], summary="Example scene configs")
def examples(svc: Service = Depends(service)) -> list[dict]:
    """The example scene configs (name and TOML text), the data folder's before the shipped ones of the same name."""
    from ..app import example_folders

    out: list[dict] = []
    for folder in example_folders(svc.datadir):
        for p in sorted(folder.glob("*.toml")):
            if p.stat().st_size <= svc.config.limits.max_config_bytes and p.name not in {e["name"] for e in out}:
                out.append({"name": p.name, "text": p.read_text(encoding="utf-8", errors="replace")})
    return out
