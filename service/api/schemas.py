"""Response models of the HTTP API (they document the OpenAPI schema)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, Field

from ..executors.base import WorkerInfo

JobState = Literal["queued", "running", "succeeded", "failed", "canceled"]


class TaskView(BaseModel):
    """One task of a job: its state, attempt, progress and frames, with the worker and log of its attempt."""

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
    """A job: state, progress, times, settings and links; ``GET /jobs/{id}`` adds its tasks."""

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
    """A page of jobs, newest first, and the number of jobs in each state."""

    jobs: list[JobView]
    counts: dict[str, int] = Field(..., description="Jobs per state; `total` is their sum.")


class FrameView(BaseModel):
    """One frame of a render or fly-through job: its task, state and, once rendered, its images."""

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
    """One output of a job: its path in the job's folder, its URL and size."""

    path: str
    url: str
    bytes: int


class Download(BaseModel):
    """A labelled link to download outputs (one file, or a zip of several)."""

    label: str
    url: str


class ResultView(BaseModel):
    """The outputs of a succeeded job: its files, its main image, download links and per-task statistics."""

    id: str
    outputs: list[OutputFile]
    image: str | None = None
    downloads: list[Download]
    stats: list[dict[str, Any]]


class AssetView(BaseModel):
    """An uploaded file (path under ``assets/``) with its size and kind; an upload also gives image or mesh sizes."""

    name: str
    kind: str | None
    bytes: int
    width: int | None = None
    height: int | None = None
    channels: int | None = None
    vertices: int | None = None
    triangles: int | None = None


class Example(BaseModel):
    """An example scene: the config's file name and its TOML text."""

    name: str
    text: str


class LimitsView(BaseModel):
    """What one job may ask of this service (``forest serve --max-…``), an upload's decode budget and the memory
    its checks use; over a limit a job or an upload is refused."""

    max_width: int = Field(..., description="Widest image, pixels (settings.width, render.width).")
    max_height: int = Field(..., description="Tallest image, pixels (settings.height, render.height).")
    max_pixels: int = Field(..., description="Most pixels, width × height.")
    max_spp: int = Field(..., description="Most samples per pixel.")
    max_trees: int = Field(..., description="Most candidate trees (settings.count, scatter.count).")
    max_frames: int = Field(..., description="Most frames in one job.")
    max_iterations: int = Field(..., description="Most look-dev iterations in a match job.")
    max_upload_bytes: int = Field(..., description="Largest upload (PUT /assets), bytes.")
    max_config_bytes: int = Field(..., description="Largest config text, bytes.")
    max_decoded_bytes: int = Field(
        ...,
        description="Largest uploaded image once decoded (width × height × channels × 4 bytes), checked from its "
        "header before anything is decoded.",
    )
    max_check_memory_bytes: int = Field(
        ..., description="Address space (RLIMIT_AS) of the child process that checks one upload, bytes."
    )
    worker_memory_bytes: int | None = Field(
        ...,
        description="The memory room (bytes) a render job is checked against at submission, from its image alone: "
        "the one the service was given, else with local workers this machine's available memory and cgroup "
        "limits, read now; null: not checked at submission. Each worker checks the render again once its trees "
        "are known, against the smaller of this and its own room.",
    )


class Health(BaseModel):
    """Liveness: the executor, worker count, jobs per state, capabilities, limits and open event streams."""

    status: str
    executor: str
    workers: int
    counts: dict[str, int]
    capabilities: dict[str, bool]
    requeued_at_start: int
    streams: int = Field(0, description="Open event streams.")
    limits: LimitsView


class WorkerList(BaseModel):
    """The executor's worker slots."""

    workers: list[WorkerInfo]


class Problem(BaseModel):
    """An error: one line saying what was wrong."""

    detail: str


ERRORS: dict[int | str, dict[str, Any]] = {
    401: {"model": Problem},
    404: {"model": Problem},
    409: {"model": Problem},
    413: {"model": Problem},
    415: {"model": Problem},
    422: {"model": Problem},
}
