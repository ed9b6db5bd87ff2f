"""The interface the dispatcher drives, from its one thread.

``capacity()``             how many more attempts may start now;
``start(run)``             start one attempt (:class:`forest.service.store.TaskRun`); returns where;
``poll(timeout)``          reports since the last call (:data:`forest.service.models.Report`);
``kill(task_id, attempt)`` stop an attempt now (cancel, lost lease);
``workers()``              what each worker slot is doing, for the page;
``close()``                stop everything.

An ``exit`` report follows every attempt, once its worker slot is free again; an attempt
whose ``exit`` comes without a ``done`` or ``error`` before it has lost its worker.
Workers are long-lived: a slot runs task after task and keeps the scenes it loaded.
"""

from __future__ import annotations

import abc
from typing import Any

from pydantic import BaseModel, Field

from ..store import TaskRun


class WorkerInfo(BaseModel):
    """One worker slot as the page shows it."""

    name: str
    executor: str
    state: str = Field(..., description="idle, busy, starting or stopped")
    pid: int | None = None
    host: str | None = None
    folder: str | None = Field(default=None, description="The worker's own working folder.")
    task_id: int | None = None
    attempt: int | None = None
    job_id: str | None = None
    task: int | None = Field(default=None, description="Index of the running task in its job.")
    job_name: str | None = None
    frame: int | None = Field(default=None, description="The frame being rendered.")
    progress: float | None = Field(default=None, description="Of the running task, 0…1.")
    since: float | None = Field(default=None, description="When the slot entered its state (epoch seconds).")
    tasks_done: int = 0
    scenes: int = Field(0, description="Scenes the worker keeps loaded.")
    variant: str | None = Field(
        default=None,
        description="The Mitsuba variant the worker renders with when a job names none: cuda_ad_rgb only where its "
        "GPU passed forest's self-check (null until the worker has said).",
    )
    variant_reason: str | None = Field(default=None, description="Why that variant (a failed GPU self-check says why).")
    gpu: str | None = Field(default=None, description="The worker's GPU (absent without one).")
    gpu_memory_mib: int | None = Field(default=None, description="That GPU's memory, MiB.")


class Executor(abc.ABC):
    """Where task attempts run.  The dispatcher is the only caller, from one thread."""

    name = "base"

    @abc.abstractmethod
    def capacity(self) -> int:
        """How many more attempts may start now."""

    @abc.abstractmethod
    def start(self, run: TaskRun) -> str:
        """Start one attempt; return a description of where it runs (for the job log)."""

    @abc.abstractmethod
    def poll(self, timeout: float) -> list[Any]:
        """Reports (progress, heartbeat, frame, result, exit) received within ``timeout`` seconds."""

    @abc.abstractmethod
    def kill(self, task_id: int, attempt: int) -> None:
        """Stop an attempt (cancel or lost lease); a no-op if it already ended."""

    @abc.abstractmethod
    def active(self) -> set[tuple[int, int]]:
        """The (task id, attempt) pairs still running."""

    @abc.abstractmethod
    def workers(self) -> list[WorkerInfo]:
        """Every worker slot and what it runs."""

    @property
    def slots(self) -> int:
        """How many attempts may run at once."""
        return len(self.workers())

    @abc.abstractmethod
    def close(self) -> None:
        """Stop every attempt and release resources."""
