"""The HTTP API and web page (FastAPI).

Routes (all JSON unless said otherwise; errors are ``{"detail": "<one line>"}``):

==========================  ==========================================================
``GET /``                   the web page (static HTML/JS/CSS under ``service/static``)
``POST /jobs``              submit; 202 + ``Location: /jobs/{id}``; ``Idempotency-Key``
                            makes a re-submit return the same job
``GET /jobs``               recent jobs, newest first (``?state=``, ``?limit=``)
``GET /jobs/{id}``          state, progress, message, tasks, links
``GET /jobs/{id}/events``   Server-Sent Events: ``snapshot``, ``state``, ``progress``,
                            ``task``, ``cancel``; resumable with ``Last-Event-ID``
``POST /jobs/{id}/cancel``  stop a job (queued tasks at once, running ones are killed)
``POST /jobs/{id}/retry``   requeue the failed/canceled tasks of a finished job
``GET /jobs/{id}/result``   outputs and statistics of a succeeded job (409 before)
``GET /jobs/{id}/log``      the job's log (text)
``GET /jobs/{id}/preview``  the latest finished pass (PNG)
``GET /jobs/{id}/files/…``  an output file
``PUT /assets/{name}``      upload a map, mesh or reference photo (checked, size-limited)
``GET /assets``             uploaded assets
``GET /examples``           example scene configs for the page
``GET /health``             liveness, queue counts, executor, capabilities
``GET /openapi.json``       the OpenAPI document
==========================  ==========================================================

Safety: the service binds to loopback unless told otherwise, and then a bearer token
is required (``Authorization: Bearer …``; ``?access_token=`` for GETs, which the page
needs for ``EventSource`` and ``<img>``).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from fastapi import APIRouter, Depends, FastAPI, Header, HTTPException, Query, Request
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from .assets import AssetError, DataDir, asset_kind, check_relative, is_inside, store_upload
from .dispatcher import Dispatcher
from .executors import Executor, LocalExecutor, RayExecutor
from .jobs import JobRequest, Limits, RequestError, prepare, request_hash
from .runner import capabilities
from .store import TERMINAL, IdempotencyConflict, Store

STATIC = Path(__file__).resolve().parent / "static"
REPO_CONFIGS = Path(__file__).resolve().parents[1] / "configs"
LOOPBACK = ("127.0.0.1", "localhost", "::1")


@dataclass
class ServiceConfig:
    data_dir: Path
    workers: int = 1
    executor: Literal["local", "ray"] = "local"
    ray_address: str | None = None
    ray_init: dict = field(default_factory=dict)
    token: str | None = None
    limits: Limits = field(default_factory=Limits)
    lease_s: float = 15.0
    heartbeat_s: float = 1.0
    max_attempts: int = 3
    nice: int = 19
    dispatch: bool = True  # False: accept jobs but start none (tests, maintenance)


# -- response models (for the OpenAPI document) ----------------------------------


class TaskView(BaseModel):
    index: int
    state: str
    attempt: int
    progress: float
    message: str
    frames: list[int] | None = None
    worker: str | None = None
    error: str | None = None


class JobView(BaseModel):
    id: str
    kind: str
    name: str | None = None
    state: Literal["queued", "running", "succeeded", "failed", "canceled"]
    priority: int
    progress: float = Field(..., ge=0.0, le=1.0)
    message: str
    error: str | None = None
    created: float
    started: float | None = None
    finished: float | None = None
    cancel_requested: bool
    settings: dict
    preview: str | None = Field(None, description="URL of the latest pass, when there is one.")
    links: dict[str, str]
    tasks: list[TaskView] | None = None


class JobList(BaseModel):
    jobs: list[JobView]
    counts: dict[str, int]


class OutputFile(BaseModel):
    path: str
    url: str
    bytes: int


class ResultView(BaseModel):
    id: str
    outputs: list[OutputFile]
    image: str | None = None
    stats: list[dict]


class AssetView(BaseModel):
    name: str
    kind: str | None
    bytes: int
    width: int | None = None
    height: int | None = None
    channels: int | None = None
    vertices: int | None = None
    triangles: int | None = None


class Example(BaseModel):
    name: str
    text: str


class Health(BaseModel):
    status: str
    executor: str
    workers: int
    counts: dict[str, int]
    capabilities: dict[str, bool]
    requeued_at_start: int


class Problem(BaseModel):
    detail: str


ERRORS = {
    401: {"model": Problem},
    404: {"model": Problem},
    409: {"model": Problem},
    413: {"model": Problem},
    415: {"model": Problem},
    422: {"model": Problem},
}


def job_view(job: dict, *, tasks: bool = False) -> dict:
    jid = job["id"]
    base = f"/jobs/{jid}"
    links = {
        "self": base,
        "events": f"{base}/events",
        "cancel": f"{base}/cancel",
        "log": f"{base}/log",
        "result": f"{base}/result",
    }
    v = {
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
    v["progress"] = min(1.0, max(0.0, float(job["progress"] or 0.0)))
    v["name"] = job["settings"].get("name")
    v["preview"] = f"{base}/preview?v={int(job['progress'] * 1000)}-{job['state']}" if job.get("preview") else None
    v["links"] = links
    if tasks and "tasks" in job:
        v["tasks"] = [
            {
                "index": t["idx"],
                "state": t["state"],
                "attempt": t["attempt"],
                "progress": t["progress"],
                "message": t["message"],
                "frames": t["spec"].get("frames"),
                "worker": t["worker"],
                "error": t["error"],
            }
            for t in job["tasks"]
        ]
    return v


def seed_examples(datadir: DataDir) -> None:
    """Make the repo's example configs and their maps available in a fresh data folder."""
    src = REPO_CONFIGS
    if not src.is_dir():
        return
    for p in src.rglob("*"):
        if not p.is_file() or asset_kind(p.name) is None or p.stat().st_size > 16 * 2**20:
            continue
        dst = datadir.assets / p.relative_to(src)
        if not dst.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(p, dst)


def create_app(cfg: ServiceConfig) -> FastAPI:
    datadir = DataDir(cfg.data_dir)
    state: dict = {}

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        lock = datadir.lock()
        if lock is None:
            raise RuntimeError(f"{datadir.root}: another forest service is using this data folder")
        seed_examples(datadir)
        store = Store(datadir.db, max_attempts=cfg.max_attempts)
        if cfg.executor == "ray":
            executor: Executor = RayExecutor(
                cfg.ray_address, slots=cfg.workers, heartbeat_s=cfg.heartbeat_s, init_kwargs=cfg.ray_init
            )
        else:
            executor = LocalExecutor(cfg.workers, heartbeat_s=cfg.heartbeat_s, nice=cfg.nice)
        dispatcher = Dispatcher(store, executor, datadir, lease_s=cfg.lease_s)
        dispatcher.paused = not cfg.dispatch
        state.update(store=store, executor=executor, dispatcher=dispatcher, caps=capabilities())
        dispatcher.start()
        app.state.store, app.state.dispatcher = store, dispatcher
        try:
            yield
        finally:
            dispatcher.stop()
            store.close()
            lock.close()

    app = FastAPI(
        title="forest render service",
        version="1",
        lifespan=lifespan,
        docs_url=None,
        redoc_url=None,
        description="Queue render, fly-through and colour-matching jobs; watch them, fetch results.",
    )
    app.state.datadir = datadir
    app.state.config = cfg

    def store() -> Store:
        return state["store"]

    def authorize(request: Request, authorization: str | None = Header(None, include_in_schema=False)) -> None:
        if not cfg.token:
            return
        supplied = None
        if authorization and authorization.lower().startswith("bearer "):
            supplied = authorization[7:].strip()
        elif request.method == "GET":
            supplied = request.query_params.get("access_token")
        if supplied is None or not hmac.compare_digest(supplied.encode(), cfg.token.encode()):
            raise HTTPException(
                401,
                "a bearer token is required (Authorization: Bearer <token>)",
                headers={"WWW-Authenticate": "Bearer"},
            )

    api = APIRouter(dependencies=[Depends(authorize)], responses={401: {"model": Problem}})

    def get_job_or_404(job_id: str, *, tasks: bool = False) -> dict:
        job = store().get_job(job_id, with_tasks=tasks) if len(job_id) == 32 else None
        if job is None:
            raise HTTPException(404, f"job {job_id} not found")
        return job

    # The two hot paths (submit, status read) answer with a JSONResponse built directly
    # from the store's rows; their schema is documented through ``responses``.
    def view_response(view: dict, status: int = 200, headers: dict | None = None) -> JSONResponse:
        return JSONResponse(view, status_code=status, headers=headers)

    @api.post(
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
        summary="Submit a render, fly-through or match job",
    )
    async def submit(
        req: JobRequest,
        idempotency_key: str | None = Header(None, max_length=200, description="Makes re-submits safe."),
    ) -> JSONResponse:
        h = request_hash(req)
        if idempotency_key is not None:
            existing = store().find_idempotent(idempotency_key)
            if existing is not None:
                if existing["request_hash"] != h:
                    raise HTTPException(409, "Idempotency-Key was already used for a different request")
                return view_response(
                    job_view(store().get_job(existing["id"], with_tasks=True), tasks=True),
                    202,
                    {"Location": f"/jobs/{existing['id']}", "Idempotent-Replayed": "true"},
                )
        try:
            prep = prepare(req, datadir, cfg.limits, state["caps"])
        except RequestError as e:
            raise HTTPException(e.status, str(e)) from None
        try:
            job, created = store().create_job(
                kind=req.kind,
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
            return view_response(job_view(store().get_job(job["id"], with_tasks=True), tasks=True), 202, headers)
        job["tasks"] = [
            {
                "idx": i,
                "state": "queued",
                "attempt": 0,
                "progress": 0.0,
                "message": "",
                "spec": spec,
                "worker": None,
                "error": None,
            }
            for i, spec in enumerate(prep.task_specs)
        ]
        return view_response(job_view(job, tasks=True), 202, headers)

    @api.get("/jobs", response_model=JobList, summary="Recent jobs, newest first")
    def list_jobs(
        state_: Literal["queued", "running", "succeeded", "failed", "canceled"] | None = Query(None, alias="state"),
        limit: int = Query(50, ge=1, le=500),
    ):
        return {"jobs": [job_view(j) for j in store().list_jobs(state=state_, limit=limit)], "counts": store().counts()}

    @api.get(
        "/jobs/{job_id}",
        response_model=None,
        responses={200: {"model": JobView}, **ERRORS},
        summary="A job's state and progress",
    )
    async def get_job(job_id: str) -> JSONResponse:
        return view_response(job_view(get_job_or_404(job_id, tasks=True), tasks=True))

    @api.post(
        "/jobs/{job_id}/cancel", status_code=202, response_model=JobView, responses=ERRORS, summary="Cancel a job"
    )
    def cancel(job_id: str):
        job = get_job_or_404(job_id)
        if job["state"] in TERMINAL:
            raise HTTPException(409, f"job {job_id} already {job['state']}")
        store().request_cancel(job_id)
        return job_view(get_job_or_404(job_id, tasks=True), tasks=True)

    @api.post(
        "/jobs/{job_id}/retry",
        status_code=202,
        response_model=JobView,
        responses=ERRORS,
        summary="Requeue the failed or canceled tasks of a finished job",
    )
    def retry(job_id: str):
        job = get_job_or_404(job_id)
        if job["state"] not in ("failed", "canceled"):
            raise HTTPException(409, f"job {job_id} is {job['state']}; only failed or canceled jobs can be retried")
        store().retry_job(job_id)
        return job_view(get_job_or_404(job_id, tasks=True), tasks=True)

    def _file_entry(job_id: str, rel: str) -> dict:
        p = datadir.job_dir(job_id) / rel
        return {"path": rel, "url": f"/jobs/{job_id}/files/{rel}", "bytes": p.stat().st_size if p.is_file() else 0}

    @api.get(
        "/jobs/{job_id}/result",
        response_model=ResultView,
        responses=ERRORS,
        summary="Outputs and statistics of a succeeded job",
    )
    def result(job_id: str):
        job = get_job_or_404(job_id)
        if job["state"] != "succeeded":
            msg = f"job {job_id} is {job['state']}"
            if job["error"]:
                msg += f": {job['error']}"
            raise HTTPException(409, msg)
        res = job["result"] or {"outputs": [], "stats": []}
        outs = [_file_entry(job_id, o) for o in res.get("outputs", [])]
        pngs = [o["url"] for o in outs if o["path"].endswith(".png") and "/" in o["path"]]
        beauty = [u for u in pngs if not any(t in u.rsplit("/", 1)[-1] for t in ("depth", "mask", "_id", "species"))]
        return {"id": job_id, "outputs": outs, "image": (beauty or pngs or [None])[0], "stats": res.get("stats", [])}

    @api.get("/jobs/{job_id}/log", response_class=PlainTextResponse, responses=ERRORS, summary="The job's log")
    def job_log(job_id: str):
        get_job_or_404(job_id)
        p = datadir.job_dir(job_id) / "job.log"
        if not p.is_file():
            return PlainTextResponse("")
        with open(p, "rb") as f:
            size = p.stat().st_size
            f.seek(max(0, size - 2**20))
            return PlainTextResponse(f.read().decode("utf-8", errors="replace"))

    @api.get(
        "/jobs/{job_id}/preview",
        responses={**ERRORS, 200: {"content": {"image/png": {}}}},
        response_class=FileResponse,
        summary="The latest finished pass as PNG",
    )
    def preview(job_id: str):
        job = get_job_or_404(job_id)
        if not job.get("preview"):
            raise HTTPException(404, f"job {job_id} has no preview yet")
        return _job_file(job_id, job["preview"], cache=False)

    @api.get(
        "/jobs/{job_id}/files/{path:path}",
        responses=ERRORS,
        response_class=FileResponse,
        summary="An output file of a job",
    )
    def job_file(job_id: str, path: str):
        get_job_or_404(job_id)
        if not (path.startswith(("out/", "preview/"))):
            raise HTTPException(404, "only out/ and preview/ files are served")
        return _job_file(job_id, path, cache=True)

    def _job_file(job_id: str, rel: str, *, cache: bool) -> FileResponse:
        try:
            check_relative(rel, field="path")
        except AssetError as e:
            raise HTTPException(404, str(e)) from None
        root = datadir.job_dir(job_id).resolve()
        p = (root / rel).resolve()
        if not is_inside(p, root) or not p.is_file():
            raise HTTPException(404, f"{rel} not found")
        headers = {"Cache-Control": "no-store"} if not cache else {}
        return FileResponse(p, headers=headers)

    @api.get(
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
    ):
        job = get_job_or_404(job_id, tasks=True)
        start = after
        if last_event_id and last_event_id.isdigit():
            start = int(last_event_id)
        snapshot = None
        if start is None:
            start = store().last_event_id(job_id)
            snapshot = job_view(job, tasks=True)

        async def stream():
            last = start
            if snapshot is not None:
                yield f"id: {last}\nevent: snapshot\ndata: {json.dumps(snapshot)}\n\n"
                if snapshot["state"] in TERMINAL:
                    return
            else:
                yield ": stream\n\n"
            quiet = 0.0
            check_state = 0.0
            while True:
                evs = store().events_after(job_id, last)
                for e in evs:
                    last = e["id"]
                    yield f"id: {e['id']}\nevent: {e['type']}\ndata: {json.dumps(e['data'])}\n\n"
                    if e["type"] == "state" and e["data"].get("state") in TERMINAL:
                        more = store().events_after(job_id, last)
                        if not more:
                            return
                if evs:
                    quiet = 0.0
                    continue
                if await request.is_disconnected():
                    return
                now = time.monotonic()
                if now - check_state > 1.0:
                    check_state = now
                    j = store().get_job(job_id)
                    if j is None or (j["state"] in TERMINAL and not store().events_after(job_id, last)):
                        return
                await asyncio.sleep(0.05)
                quiet += 0.05
                if quiet >= 15.0:
                    quiet = 0.0
                    yield ": keep-alive\n\n"

        return StreamingResponse(
            stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
        )

    @api.put(
        "/assets/{name}",
        status_code=201,
        response_model=AssetView,
        responses=ERRORS,
        summary="Upload a map, mesh or reference photo (the raw file as the body)",
    )
    async def upload(name: str, request: Request):
        limit = cfg.limits.max_upload_bytes
        length = request.headers.get("content-length")
        if length is not None and length.isdigit() and int(length) > limit:
            raise HTTPException(413, f"upload is larger than the {limit} byte limit")
        chunks: list[bytes] = []
        size = 0
        async for chunk in request.stream():
            size += len(chunk)
            if size > limit:
                raise HTTPException(413, f"upload is larger than the {limit} byte limit")
            chunks.append(chunk)
        try:
            return await asyncio.to_thread(store_upload, datadir, name, iter(chunks), limit)
        except AssetError as e:
            raise HTTPException(e.status, f"{name}: {e}") from None

    @api.get("/assets", response_model=list[AssetView], summary="Uploaded assets")
    def assets():
        return datadir.list_assets()

    @api.get("/examples", response_model=list[Example], summary="Example scene configs")
    def examples():
        out = []
        for folder in (datadir.configs, REPO_CONFIGS):
            if folder.is_dir():
                for p in sorted(folder.glob("*.toml")):
                    if p.stat().st_size <= cfg.limits.max_config_bytes and p.name not in {e["name"] for e in out}:
                        out.append({"name": p.name, "text": p.read_text(encoding="utf-8", errors="replace")})
        return out

    @api.get("/health", response_model=Health, summary="Liveness and queue counts")
    def health():
        return {
            "status": "ok",
            "executor": state["executor"].name,
            "workers": cfg.workers,
            "counts": store().counts(),
            "capabilities": state["caps"],
            "requeued_at_start": store().requeued_on_open,
        }

    app.include_router(api)

    @app.get("/", include_in_schema=False)
    def index():
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.exception_handler(RequestError)
    async def _request_error(request: Request, exc: RequestError):
        return JSONResponse({"detail": str(exc)}, status_code=exc.status)

    return app


def is_loopback(host: str) -> bool:
    return host in LOOPBACK or host.startswith("127.")
