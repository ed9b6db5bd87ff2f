"""``GET /jobs/{id}/events``: Server-Sent Events of one job.

Event types: ``snapshot`` (the job's view, first, when no position is given), ``state``,
``progress`` (per pass: task, job progress, frame, passes, ETA, preview), ``frame`` (a
frame is on disk), ``task``, ``cancel``, ``retry``, ``outputs``.  Each carries its id;
``Last-Event-ID`` (or ``?after=``) resumes after it.  The stream ends after the job's
final state.

A stream sleeps on a notification from the store (:mod:`forest.service.notify`) and
reads the store only when something was written for its job — in a worker thread, so
the event loop never waits on SQLite; a comment line every 15 s keeps proxies from
closing a quiet stream.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator

from fastapi import APIRouter, Depends, Header, Query, Request
from fastapi.responses import StreamingResponse

from ..store import TERMINAL
from ..views import job_view
from .deps import Service, job_or_404, service
from .schemas import ERRORS

router = APIRouter()
KEEP_ALIVE_S = 15.0


@router.get(
    "/jobs/{job_id}/events",
    responses={**ERRORS, 200: {"content": {"text/event-stream": {}}}},
    response_class=StreamingResponse,
    summary="Server-Sent Events for a job",
)
async def events(
    job_id: str,
    request: Request,
    after: int | None = Query(None, ge=0, le=2**62, description="Replay events after this id."),
    last_event_id: str | None = Header(None, max_length=20, include_in_schema=False),
    svc: Service = Depends(service),
) -> StreamingResponse:
    """Stream a job's events as ``text/event-stream``: first a ``snapshot`` (the job as ``GET /jobs/{id}`` shows it),
    then each event as it happens (``id``: its number), with keep-alive comments every 15 s.

    With ``after`` or a ``Last-Event-ID`` header it replays the events after that id instead of the snapshot.
    The stream ends once the job has finished and every event has been sent.
    """
    store = svc.db

    def opening() -> tuple[int, dict | None]:
        job = job_or_404(svc, job_id, tasks=True)
        start = after
        if last_event_id and last_event_id.isdigit():
            start = int(last_event_id)
        if start is not None:
            return start, None
        return store.last_event_id(job_id), job_view(job, tasks=True, frames=store.frames(job_id))

    start, snapshot = await asyncio.to_thread(opening)

    async def stream() -> AsyncIterator[str]:
        last = start
        with svc.notifier.subscribe(job_id) as woken:
            if snapshot is not None:
                yield f"id: {last}\nevent: snapshot\ndata: {json.dumps(snapshot)}\n\n"
                if snapshot["state"] in TERMINAL:
                    return
            else:
                yield ": stream\n\n"
            while True:
                woken.clear()  # before reading: a write after the read sets it again
                evs = await asyncio.to_thread(store.events_after, job_id, last)
                ended = False
                for e in evs:
                    last = e["id"]
                    yield f"id: {e['id']}\nevent: {e['type']}\ndata: {json.dumps(e['data'])}\n\n"
                    ended = ended or (e["type"] == "state" and e["data"].get("state") in TERMINAL)
                if evs:
                    if ended and not await asyncio.to_thread(store.events_after, job_id, last, 1):
                        return
                    continue
                try:
                    await asyncio.wait_for(woken.wait(), KEEP_ALIVE_S)
                except TimeoutError:
                    if await request.is_disconnected():
                        return
                    job = await asyncio.to_thread(store.get_job, job_id)
                    if job is None or job["state"] in TERMINAL:
                        return
                    yield ": keep-alive\n\n"

    return StreamingResponse(
        stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    )
