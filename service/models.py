"""The typed contract between the service and its workers: task specs, orders and reports.

One module, three users: :mod:`forest.service.store` keeps a :class:`TaskSpec` per task
and applies :data:`Report`\\ s, :mod:`forest.service.runner` executes a spec and emits
reports, and the executors carry both between them — as JSON lines over a pipe to a
local worker process (:mod:`forest.service.worker`), or as pickled objects through Ray.

A spec names no absolute path.  Inputs are the job's files by their job-relative path
and the SHA-256 of their content, so a worker on another machine fetches them from
Ray's object store into a content-addressed cache of its own, and two specs with the
same config and the same input bytes share one loaded scene (:attr:`TaskSpec.scene_key`).

Reports flow one way, worker → service, each naming its ``(task_id, attempt)``; the
store ignores every report of an attempt it no longer runs.  A report may carry
``files`` (job-relative path → bytes) when the worker does not share the service's
disk; the dispatcher writes them into the job folder before it records the report.
"""

from __future__ import annotations

import hashlib
import json
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

Kind = Literal["render", "flythrough", "match", "rib", "usd"]
Variant = Literal["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"]
#: Job kinds whose tasks render frames (each frame has an EXR, a PNG and a thumbnail).
FRAME_KINDS = ("render", "flythrough")


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class MatchSpec(_Frozen):
    """The look-dev arguments of a match task (``None``: the config's ``[lookdev]`` or the default)."""

    reference: str
    iterations: int | None = None
    resolution: int | None = None
    spp: int | None = None
    params: tuple[str, ...] | None = None
    mode: str | None = None


class Resources(_Frozen):
    """What one task reserves on a Ray cluster (``None``: 1 CPU; a GPU for ``cuda_*`` variants)."""

    cpus: float | None = None
    gpus: float | None = None


class TaskSpec(_Frozen):
    """Everything a worker needs to run one task, stored with the task (no absolute paths)."""

    job_id: str
    kind: Kind
    index: int = Field(..., ge=0, description="The task's position in its job.")
    config: str = Field(default="", description="The scene config as TOML text (kept once, with the job).")
    overrides: dict[str, Any] = Field(default_factory=dict, description="Dotted config keys set by the request.")
    variant: Variant | None = None
    preview: bool = False
    frames: tuple[int, ...] | None = Field(default=None, description="Frames of this task; None: not a frame task.")
    output: str = Field(..., description="Job-relative output: a file, a #### pattern or a folder.")
    match: MatchSpec | None = None
    renderman22: bool = False
    quick_look: bool = True
    resources: Resources = Field(default_factory=Resources)
    inputs: dict[str, str] = Field(default_factory=dict, description="Job-relative input path -> SHA-256.")
    skip_frames: tuple[int, ...] = Field((), description="Frames whose outputs the service already holds.")
    memory_bytes: int | None = Field(
        default=None,
        description="The room (bytes) the service says its workers have (Limits.worker_memory_bytes); a worker "
        "checks a render against the smaller of it and its own room (None: its own alone).",
    )

    @property
    def scene_key(self) -> str:
        """Same config, overrides and input bytes ⇒ same key ⇒ the same loaded scene."""
        return digest({"config": self.config, "overrides": self.overrides, "inputs": self.inputs})

    @property
    def inputs_key(self) -> str:
        """Same input bytes under the same names ⇒ the same folder of inputs."""
        return digest(self.inputs)


class TaskOrder(_Frozen):
    """One attempt of one task, as an executor hands it to a worker."""

    task_id: int
    attempt: int
    spec: TaskSpec
    job_dir: str | None = Field(
        None, description="The service's job folder when the worker shares its disk (outputs go there directly)."
    )
    heartbeat_s: float = 1.0


def digest(value: Any) -> str:
    """SHA-256 of a JSON value in canonical form (sorted keys), as hex."""
    return hashlib.sha256(json.dumps(value, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


# -- reports ----------------------------------------------------------------------------


class _Report(BaseModel):
    model_config = ConfigDict(extra="forbid", ser_json_bytes="base64", val_json_bytes="base64")
    task_id: int
    attempt: int
    files: dict[str, bytes] = Field(default_factory=dict, description="Shipped outputs (no shared disk).")


class Heartbeat(_Report):
    """The attempt is alive: renews its lease."""

    type: Literal["heartbeat"] = "heartbeat"


class Progress(_Report):
    """Progress of a running attempt; ``preview`` names the newest image of it (job-relative)."""

    type: Literal["progress"] = "progress"
    fraction: float = Field(0.0, description="Of the whole task, 0…1.")
    message: str = ""
    frame: int | None = None
    passes_done: int | None = None
    passes_total: int | None = None
    eta_s: float | None = Field(default=None, description="Seconds left, from the measured pass and frame times.")
    preview: str | None = None
    trees: int | None = Field(default=None, description="Trees in the scene, once it is loaded.")


class FrameDone(_Report):
    """One frame of the task is on disk (``resumed``: it was there already and was not rendered again)."""

    type: Literal["frame"] = "frame"
    frame: int
    seconds: float = 0.0
    outputs: list[str] = Field(default_factory=list)
    thumb: str | None = None
    resumed: bool = False


class Log(_Report):
    """A line for the task's log."""

    type: Literal["log"] = "log"
    line: str


class TaskResult(BaseModel):
    """What a finished task wrote and measured."""

    model_config = ConfigDict(extra="forbid")
    outputs: list[str] = Field(default_factory=list, description="Job-relative files, sorted.")
    stats: dict[str, Any] | None = None
    preview: str | None = None
    trees: int | None = None
    resumed_frames: list[int] = Field(default_factory=list)


class Done(_Report):
    """The attempt succeeded."""

    type: Literal["done"] = "done"
    result: TaskResult


class Failed(_Report):
    """The attempt failed: ``user`` for a mistake in the job (not retried), else a crash."""

    type: Literal["error"] = "error"
    error: str
    user: bool = False
    param: str | None = Field(default=None, description="The library parameter the error is about (ParameterError).")
    traceback: str | None = None


class Exit(_Report):
    """The attempt's worker slot is free again: after done/error, or because the worker died."""

    type: Literal["exit"] = "exit"
    code: int | None = None


class Capability(_Report):
    """What a worker renders with when a task names no variant, sent once as it starts (``task_id`` and ``attempt``
    −1: about no task): :func:`forest.render.variant.capability`. The executor keeps it for the worker list; it is
    no :data:`Report`."""

    type: Literal["capability"] = "capability"
    variant: str
    variant_reason: str = ""
    gpu: str | None = None
    gpu_memory_mib: int | None = None


Report = Annotated[Heartbeat | Progress | FrameDone | Log | Done | Failed | Exit, Field(discriminator="type")]
REPORT = TypeAdapter(Report)


def parse_report(line: str | bytes) -> Heartbeat | Progress | FrameDone | Log | Done | Failed | Exit:
    """A report from one JSON line (raises ``pydantic.ValidationError`` for anything else)."""
    return REPORT.validate_json(line)
