"""Jobs: submit, list, look at, cancel, resume, requeue a task or a frame, delete.

========================================  ===================================================
``POST /jobs``                            submit; 202 + ``Location``; ``Idempotency-Key``
                                          makes a re-submit return the same job
``GET /jobs``                             newest first; ``?state=``, ``?name=`` (part of it)
``GET /jobs/{id}``                        state, progress, times, ETA, tasks
``DELETE /jobs/{id}``                     forget a finished job and delete its folder
``GET /jobs/{id}/frames``                 every frame: state, time, thumbnail, files
``POST /jobs/{id}/cancel``                stop (queued tasks at once, running ones killed)
``POST /jobs/{id}/resume``                run the failed/canceled tasks again; frames on disk
                                          are kept (``/retry`` is the same)
``POST /jobs/{id}/tasks/{i}/requeue``     render task ``i`` again (its frames' files go)
``POST /jobs/{id}/frames/{f}/requeue``    render frame ``f`` again (its task's other frames stay)
========================================  ===================================================
"""

from __future__ import annotations

import shutil
import time
from typing import Literal

from fastapi import APIRouter, Depends, Header, HTTPException, Query, Response
from fastapi.responses import JSONResponse

from ..jobs import JobRequest, RequestError, prepare, request_hash
from ..models import FRAME_KINDS
from ..retention import write_manifest
from ..runner import frame_files
from ..store import JOB_STATES, TERMINAL, IdempotencyConflict, task_spec
from ..views import frame_views, job_view
from .deps import Service, job_or_404, service
from .schemas import ERRORS, FrameView, JobList, JobView

router = APIRouter()
State = Literal["queued", "running", "succeeded", "failed", "canceled"]


def _view(svc: Service, job_id: str) -> dict:
    job = job_or_404(svc, job_id, tasks=True)
    return job_view(job, tasks=True, frames=svc.db.frames(job_id))


# The two hot paths (submit, status read) answer with a JSONResponse built from the
# store's rows; their schema is documented through ``responses``.
@router.post(
    "/jobs",
    status_code=202,
    response_model=None,
    responses={
        202: {
            "model": JobView,
            "description": "Accepted; `Location` names the job.",
            "headers": {"Location": {"schema": {"type": "string"}}},
        },
        **ERRORS,
    },
    summary="Submit a render, fly-through, match or export job",
)
def submit(
    req: JobRequest,
    idempotency_key: str | None = Header(None, max_length=200, description="Makes re-submits safe."),
    svc: Service = Depends(service),
) -> JSONResponse:
    """Check the request, lay out the job's folder and queue its tasks; 202 with the job and its ``Location``.

    The same ``Idempotency-Key`` with the same request returns the first job (``Idempotent-Replayed: true``);
    with a different request it is a 409.
    """
    store = svc.db
    h = request_hash(req)
    if idempotency_key is not None:
        existing = store.find_idempotent(idempotency_key)
        if existing is not None:
            if existing["request_hash"] != h:
                raise HTTPException(409, "Idempotency-Key was already used for a different request")
            return JSONResponse(
                _view(svc, existing["id"]),
                202,
                {"Location": f"/jobs/{existing['id']}", "Idempotent-Replayed": "true"},
            )
    try:
        prep = prepare(req, svc.datadir, svc.config.limits, svc.caps, local=svc.config.executor == "local")
    except RequestError as e:
        raise HTTPException(e.status, str(e)) from None
    try:
        job, created = store.create_job(
            kind=req.kind,
            name=prep.name,
            config=req.config,
            settings=prep.settings,
            priority=req.priority,
            task_specs=prep.task_specs,
            idempotency_key=idempotency_key,
            request_hash=h,
            job_id=prep.job_id,
        )
    except IdempotencyConflict:
        shutil.rmtree(prep.job_dir, ignore_errors=True)
        raise HTTPException(409, "Idempotency-Key was already used for a different request") from None
    headers = {"Location": f"/jobs/{job['id']}"}
    if not created:
        shutil.rmtree(prep.job_dir, ignore_errors=True)
        headers["Idempotent-Replayed"] = "true"
        return JSONResponse(_view(svc, job["id"]), 202, headers)
    job["tasks"] = [
        {
            "idx": s.index,
            "state": "queued",
            "attempt": 0,
            "max_attempts": store.max_attempts,
            "progress": 0.0,
            "message": "",
            "frames": list(s.frames) if s.frames is not None else None,
            "worker": None,
            "error": None,
        }
        for s in prep.task_specs
    ]
    return JSONResponse(job_view(job, tasks=True, frames=[]), 202, headers)


@router.get("/jobs", response_model=JobList, summary="Jobs, newest first, filtered by state and name")
def list_jobs(
    state: State | None = Query(None),
    name: str | None = Query(None, max_length=200, description="Jobs whose name contains this (any case)."),
    limit: int = Query(50, ge=1, le=500),
    svc: Service = Depends(service),
) -> dict:
    """Up to ``limit`` jobs, newest first, with the number of jobs in each state."""
    store = svc.db
    now = time.time()
    counts = store.counts()
    counts["total"] = sum(counts[s] for s in JOB_STATES)
    return {
        "jobs": [job_view(j, now=now) for j in store.list_jobs(state=state, name=name, limit=limit)],
        "counts": counts,
    }


@router.get(
    "/jobs/{job_id}",
    response_model=None,
    responses={200: {"model": JobView}, **ERRORS},
    summary="A job's state, progress, times and tasks",
)
def get_job(job_id: str, svc: Service = Depends(service)) -> JSONResponse:
    """The job with its tasks and frames; a forgotten job's saved view while its folder remains."""
    job = job_or_404(svc, job_id, tasks=True, archived=True)
    if job.get("archived"):
        return JSONResponse({k: v for k, v in job.items() if k in JobView.model_fields})
    return JSONResponse(job_view(job, tasks=True, frames=svc.db.frames(job_id)))


@router.delete(
    "/jobs/{job_id}", status_code=204, responses=ERRORS, summary="Forget a finished job and delete its outputs"
)
def delete_job(job_id: str, svc: Service = Depends(service)) -> Response:
    """Remove a finished job from the store and delete its folder; 409 while it is queued or running."""
    job = job_or_404(svc, job_id, archived=True)
    if job["state"] not in TERMINAL:
        raise HTTPException(409, f"job {job_id} is {job['state']}; cancel it first")
    try:
        svc.db.delete_job(job_id)
    except ValueError as e:
        raise HTTPException(409, str(e)) from None
    shutil.rmtree(svc.datadir.job_dir(job_id), ignore_errors=True)
    return Response(status_code=204)


@router.get("/jobs/{job_id}/frames", response_model=list[FrameView], responses=ERRORS, summary="A job's frames")
def frames(job_id: str, svc: Service = Depends(service)) -> list[dict]:
    """Each frame of a frame job with its task, state, attempt, time and images; empty for other kinds."""
    job = job_or_404(svc, job_id, tasks=True, archived=True)
    if job.get("archived"):
        return job.get("frame_list") or []
    return frame_views(job, svc.db.frames(job_id))


@router.post("/jobs/{job_id}/cancel", status_code=202, response_model=JobView, responses=ERRORS, summary="Cancel a job")
def cancel(job_id: str, svc: Service = Depends(service)) -> dict:
    """Cancel the job: its queued tasks at once, its running ones at the dispatcher's next tick; 409 once finished."""
    job = job_or_404(svc, job_id)
    if job["state"] in TERMINAL:
        raise HTTPException(409, f"job {job_id} already {job['state']}")
    after = svc.db.request_cancel(job_id)
    if after is not None and after["state"] in TERMINAL:
        write_manifest(svc.datadir, svc.db, job_id)
    return _view(svc, job_id)


def _resume(job_id: str, svc: Service) -> dict:
    job = job_or_404(svc, job_id)
    if job["state"] not in ("failed", "canceled"):
        raise HTTPException(409, f"job {job_id} is {job['state']}; only failed or canceled jobs can be resumed")
    svc.db.resume_job(job_id)
    return _view(svc, job_id)


@router.post(
    "/jobs/{job_id}/resume",
    status_code=202,
    response_model=JobView,
    responses=ERRORS,
    summary="Run the failed or canceled tasks of a finished job again; frames on disk are kept",
)
def resume(job_id: str, svc: Service = Depends(service)) -> dict:
    """Queue the failed and canceled tasks of a failed or canceled job again (frames on disk are kept); else 409."""
    return _resume(job_id, svc)


@router.post(
    "/jobs/{job_id}/retry",
    status_code=202,
    response_model=JobView,
    responses=ERRORS,
    summary="The same as /resume",
    deprecated=True,
)
def retry(job_id: str, svc: Service = Depends(service)) -> dict:
    """Deprecated: the same as ``POST /jobs/{job_id}/resume``."""
    return _resume(job_id, svc)


def _drop_frame_files(svc: Service, job: dict, task: dict, frames: list[int]) -> None:
    if "spec" not in task:
        return
    spec = task_spec(task)
    if spec.kind not in FRAME_KINDS:
        return
    root = svc.datadir.job_dir(job["id"])
    for f in frames:
        for rel in (*frame_files(spec, f), f"thumbs/frame_{f:04d}.png"):
            (root / rel).unlink(missing_ok=True)


@router.post(
    "/jobs/{job_id}/tasks/{index}/requeue",
    status_code=202,
    response_model=JobView,
    responses=ERRORS,
    summary="Run one finished task again (its frames are rendered anew)",
)
def requeue_task(job_id: str, index: int, svc: Service = Depends(service)) -> dict:
    """Delete the task's frames and queue the finished task again; 409 while it is queued or running."""
    job = job_or_404(svc, job_id)
    task = svc.db.get_task(job_id, index)
    if task is None:
        raise HTTPException(404, f"job {job_id} has no task {index}")
    if task["state"] not in TERMINAL:
        raise HTTPException(409, f"task {index} is {task['state']}")
    _drop_frame_files(svc, job, task, list(task["frames"] or ()))
    try:
        svc.db.requeue_task(job_id, index)
    except ValueError as e:
        raise HTTPException(409, str(e)) from None
    return _view(svc, job_id)


@router.post(
    "/jobs/{job_id}/frames/{frame}/requeue",
    status_code=202,
    response_model=JobView,
    responses=ERRORS,
    summary="Render one frame again (the other frames of its task stay on disk)",
)
def requeue_frame(job_id: str, frame: int, svc: Service = Depends(service)) -> dict:
    """Delete one frame and queue it again (its task's other frames stay); 409 while its task is queued or running."""
    job = job_or_404(svc, job_id, tasks=True)
    task = next((t for t in job["tasks"] if frame in (t["frames"] or ())), None)
    if task is None or job["kind"] not in FRAME_KINDS:
        raise HTTPException(404, f"job {job_id} has no frame {frame}")
    if task["state"] not in TERMINAL:
        raise HTTPException(409, f"frame {frame} is in task {task['idx']}, which is {task['state']}")
    _drop_frame_files(svc, job, svc.db.get_task(job_id, task["idx"]) or {}, [frame])
    try:
        svc.db.requeue_task(job_id, task["idx"], frames=[frame])
    except ValueError as e:
        raise HTTPException(409, str(e)) from None
    return _view(svc, job_id)
