"""Response models of the HTTP API (they document the OpenAPI schema)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from ..executors.base import WorkerInfo

JobState = Literal["queued", "running", "succeeded", "failed", "canceled"]


class TaskView(BaseModel):
    index: int
    state: str
    attempt: int
    max_attempts: int
    progress: float
    message: str
    frames: list[int] | None = None
    frames_done: list[int] = Field(default_factory=list)
    frame: int | None = Field(default=None, description="The frame being rendered.")
    passes_done: int | None = None
    passes_total: int | None = None
    started: float | None = None
    finished: float | None = None
    seconds: float | None = Field(default=None, description="Time of the attempt (so far, while it runs).")
    eta_s: float | None = None
    worker: str | None = None
    error: str | None = None
    log: str
    preview: str | None = None


class JobView(BaseModel):
    id: str
    kind: str
    name: str | None = None
    state: JobState
    priority: int
    progress: float = Field(..., ge=0.0, le=1.0)
    message: str
    error: str | None = None
    created: float = Field(..., description="Submission time (epoch seconds).")
    started: float | None = None
    finished: float | None = None
    elapsed_s: float | None = None
    eta_s: float | None = Field(default=None, description="Seconds left, from measured pass and task times.")
    cancel_requested: bool
    settings: dict[str, Any]
    trees: int | None = Field(default=None, description="Trees in the scene (known once a worker loaded it).")
    frames_total: int = 0
    frames_done: int = 0
    outputs_deleted: bool = False
    archived: bool = Field(False, description="Forgotten by the store; its folder is still on disk.")
    preview: str | None = Field(default=None, description="URL of the newest image, when there is one.")
    links: dict[str, str]
    tasks: list[TaskView] | None = None


class JobList(BaseModel):
    jobs: list[JobView]
    counts: dict[str, int] = Field(..., description="Jobs per state; `total` is their sum.")


class FrameView(BaseModel):
    frame: int
    task: int
    state: str = Field(..., description="done, rendering, queued, failed or canceled")
    attempt: int
    seconds: float | None = None
    resumed: bool = False
    thumb: str | None = None
    preview: str | None = None
    exr: str | None = None
    png: str | None = None
    error: str | None = None


class OutputFile(BaseModel):
    path: str
    url: str
    bytes: int


class Download(BaseModel):
    label: str
    url: str


class ResultView(BaseModel):
    id: str
    outputs: list[OutputFile]
    image: str | None = None
    downloads: list[Download]
    stats: list[dict[str, Any]]


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
    streams: int = Field(0, description="Open event streams.")


class WorkerList(BaseModel):
    workers: list[WorkerInfo]


class Problem(BaseModel):
    detail: str


ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": Problem},
    404: {"model": Problem},
    409: {"model": Problem},
    413: {"model": Problem},
    415: {"model": Problem},
    422: {"model": Problem},
}
