"""Executors: where task attempts run — local worker processes or a Ray cluster.

See :mod:`.base` for the interface the dispatcher drives.
"""

from .base import Executor, WorkerInfo
from .local import LocalExecutor
from .ray import RayExecutor

__all__ = ["Executor", "LocalExecutor", "RayExecutor", "WorkerInfo"]
