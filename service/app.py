"""The HTTP API and web page (FastAPI): :func:`create_app` wires the routers to a running service.

Routers, one concern each (every route is documented in its module and in ``/openapi.json``):

* :mod:`.api.jobs` — submit, list and filter, look at, cancel, resume, requeue a task or
  a frame, delete;
* :mod:`.api.files` — result, single files, zip downloads, preview, logs;
* :mod:`.api.events` — Server-Sent Events;
* :mod:`.api.assets` — uploads (folders kept) and their list;
* :mod:`.api.system` — health, workers, example scenes.

Errors are ``{"detail": "<one line>"}``, a malformed request's too (the first problem,
named by its JSON field in the config's words: ``settings.spp: must be >= 1, got 0``).  Safety: the service binds to loopback unless
told otherwise, and then a bearer token is required (``Authorization: Bearer …``;
``?access_token=`` for GETs, which the page needs for ``EventSource`` and ``<img>``).
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException

from .api import assets, events, files, jobs, system
from .api.deps import Service, authorize
from .api.schemas import Problem
from .assets import DataDir, asset_kind, remove_partial_uploads
from .dispatcher import Dispatcher
from .executors import Executor, LocalExecutor, RayExecutor
from .jobs import Limits, RequestError, validation_line
from .notify import Notifier
from .retention import Retention
from .runner import capabilities
from .store import Store

STATIC = Path(__file__).resolve().parent / "static"
LOOPBACK = ("127.0.0.1", "localhost", "::1")


@dataclass
class ServiceConfig:
    """How ``forest serve`` runs: data folder, executor and workers, token, limits, retention, leases, retries."""

    data_dir: Path
    workers: int = 1
    executor: Literal["local", "ray"] = "local"
    ray_address: str | None = None
    ray_init: dict = field(default_factory=dict)
    token: str | None = None
    limits: Limits = field(default_factory=Limits)
    retention: Retention = field(default_factory=Retention)
    lease_s: float = 15.0
    heartbeat_s: float = 1.0
    max_attempts: int = 3
    nice: int = 19
    worker_idle_s: float = 600.0
    worker_scenes: int = 1
    seed_examples: bool = True  # copy the example scenes' maps into a data folder's assets/
    dispatch: bool = True  # False: accept jobs but start none (tests, maintenance)


def example_folders(datadir: DataDir) -> list[Path]:
    """Where the page's example scenes come from: the data folder's ``configs/``, then the shipped ones."""
    from forest.example_scenes import examples_root

    return [p for p in (datadir.configs, examples_root()) if p.is_dir()]


def seed_examples(datadir: DataDir) -> None:
    """Make the shipped example scenes' maps available in a fresh data folder (``assets/maps/…``)."""
    from forest.example_scenes import examples_root

    src = examples_root()
    if src.is_dir():
        for p in src.rglob("*"):
            if not p.is_file() or asset_kind(p.name) is None or p.stat().st_size > 16 * 2**20:
                continue
            dst = datadir.assets / p.relative_to(src)
            if not dst.exists():
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(p, dst)


def make_executor(cfg: ServiceConfig, datadir: DataDir) -> Executor:
    """The executor ``cfg`` names: Ray tasks on a cluster, or local worker processes (the default)."""
    if cfg.executor == "ray":
        return RayExecutor(
            cfg.ray_address,
            slots=cfg.workers,
            jobs=datadir.jobs,
            heartbeat_s=cfg.heartbeat_s,
            scenes=cfg.worker_scenes,
            init_kwargs=cfg.ray_init,
        )
    return LocalExecutor(
        cfg.workers,
        root=datadir.workers,
        jobs=datadir.jobs,
        heartbeat_s=cfg.heartbeat_s,
        nice=cfg.nice,
        idle_s=cfg.worker_idle_s,
        scenes=cfg.worker_scenes,
    )


def create_app(cfg: ServiceConfig) -> FastAPI:
    """The FastAPI app of the service over ``cfg.data_dir``: routes, page and static files; its lifespan locks the data
    folder and runs the store, executor and dispatcher.
    """
    datadir = DataDir(cfg.data_dir)
    svc = Service(config=cfg, datadir=datadir, notifier=Notifier())

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        lock = datadir.lock()
        if lock is None:
            raise RuntimeError(f"{datadir.root}: another forest service is using this data folder")
        remove_partial_uploads(datadir)  # a killed service's half-stored uploads
        if cfg.seed_examples:
            seed_examples(datadir)
        store = Store(datadir.db, max_attempts=cfg.max_attempts, on_events=svc.notifier.publish)
        executor = make_executor(cfg, datadir)
        dispatcher = Dispatcher(store, executor, datadir, lease_s=cfg.lease_s, retention=cfg.retention)
        dispatcher.paused = not cfg.dispatch
        svc.store, svc.executor, svc.dispatcher, svc.caps = store, executor, dispatcher, capabilities()
        dispatcher.start()
        try:
            yield
        finally:
            dispatcher.stop()
            store.close()
            lock.close()

    app = FastAPI(
        title="forest render service",
        version="2",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        description="Queue renders, fly-throughs, colour matches and exports; watch them refine; download the results.",
    )
    app.state.service = svc
    api = APIRouter(dependencies=[Depends(authorize)], responses={401: {"model": Problem}, 422: {"model": Problem}})
    for module in (jobs, files, events, assets, system):
        api.include_router(module.router)
    app.include_router(api)

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.exception_handler(RequestValidationError)
    async def _validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
        if isinstance(exc.body, (bytes, bytearray)):  # a body sent as something other than JSON: never echoed
            kind = request.headers.get("content-type") or "no Content-Type"
            return JSONResponse({"detail": f"body: must be JSON sent as application/json, got {kind[:60]}"}, 415)
        return JSONResponse({"detail": validation_line(list(exc.errors()), exc.body)}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
        detail = body_error(exc.__cause__) if exc.status_code == 400 else None
        if detail is not None:
            return JSONResponse({"detail": detail}, status_code=400)
        return await http_exception_handler(request, exc)

    @app.exception_handler(RequestError)
    async def _request_error(_request: Request, exc: RequestError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=exc.status)

    return app


def body_error(cause: BaseException | None) -> str | None:
    """One line for a request body FastAPI could not read as JSON, from the error behind its generic 400: text
    that is not UTF-8 (where), JSON nested past Python's recursion limit.  None for other causes."""
    if isinstance(cause, UnicodeDecodeError):
        bad = cause.object[cause.start : cause.start + 1]
        return f"body: not UTF-8 text (byte 0x{bad.hex() or '??'} at position {cause.start})"
    if isinstance(cause, RecursionError):
        return "body: JSON nested too deeply"
    return None


def is_loopback(host: str) -> bool:
    """Whether ``host`` is a loopback address (``localhost``, ``::1``, 127.x.x.x), which may serve without a token."""
    return host in LOOPBACK or host.startswith("127.")
