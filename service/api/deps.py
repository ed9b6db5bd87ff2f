"""What every router needs: the running service, authorisation, and job lookup.

Route handlers are plain (``def``) functions unless they stream: FastAPI runs them in
its thread pool, so store access never blocks the event loop.  The two streaming
handlers (events, uploads) hand their store work to threads themselves.
"""

from __future__ import annotations

import hmac
from dataclasses import dataclass, field
from typing import Any

from fastapi import Header, HTTPException, Request

from ..assets import AssetError, DataDir
from ..dispatcher import Dispatcher
from ..executors import Executor
from ..notify import Notifier
from ..retention import read_manifest
from ..store import Store


@dataclass
class Service:
    """The parts of a running service, shared by the routers (``app.state.service``)."""

    config: Any  # forest.service.app.ServiceConfig
    datadir: DataDir
    notifier: Notifier
    caps: dict[str, bool] = field(default_factory=dict)
    store: Store | None = None
    executor: Executor | None = None
    dispatcher: Dispatcher | None = None

    @property
    def db(self) -> Store:
        """The job store; 503 while the service is still starting."""
        if self.store is None:
            raise HTTPException(503, "the service is starting")
        return self.store


def service(request: Request) -> Service:
    """The running :class:`Service` (a FastAPI dependency)."""
    return request.app.state.service


def authorize(request: Request, authorization: str | None = Header(None, include_in_schema=False)) -> None:
    """A bearer token when the service has one (``?access_token=`` for GETs: EventSource, ``<img>``)."""
    token = request.app.state.service.config.token
    if not token:
        return
    supplied = None
    if authorization and authorization.lower().startswith("bearer "):
        supplied = authorization[7:].strip()
    elif request.method == "GET":
        supplied = request.query_params.get("access_token")
    if supplied is None or not hmac.compare_digest(supplied.encode(), token.encode()):
        raise HTTPException(
            401, "a bearer token is required (Authorization: Bearer <token>)", headers={"WWW-Authenticate": "Bearer"}
        )


def job_or_404(svc: Service, job_id: str, *, tasks: bool = False, archived: bool = False) -> dict:
    """The store's job, or (``archived``) the view saved in a forgotten job's folder; else 404."""
    job = svc.db.get_job(job_id, with_tasks=tasks) if len(job_id) == 32 else None
    if job is None and archived and len(job_id) == 32:
        try:
            job = read_manifest(svc.datadir, job_id)
        except AssetError:
            job = None
    if job is None:
        raise HTTPException(404, f"job {job_id} not found")
    return job
