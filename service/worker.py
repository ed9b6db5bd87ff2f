"""A local worker process: takes task after task and keeps loaded scenes between them.

Started by :class:`forest.service.executors.local.LocalExecutor` as
``python -m forest.service.worker FD FOLDER``, one per executor slot:

* reads one :class:`~forest.service.models.TaskOrder` per line from stdin and runs it
  with :func:`forest.service.runner.execute`, one at a time;
* writes JSON-line reports to file descriptor ``FD``: a ``heartbeat`` every
  ``order.heartbeat_s`` seconds while a task runs (from a thread: the lease),
  ``progress``, ``frame`` and ``log`` from the runner, then exactly one ``done`` or
  ``error`` per task;
* keeps a :class:`~forest.service.scenecache.SceneCache` (``$FOREST_WORKER_SCENES``
  scenes, default 1; 0 loads every task's scene anew) and its inputs in ``FOLDER`` (a content-addressed store of its own);
* imports the renderer as it starts, so the first task does not wait for it, and sends
  one ``capability`` report (task and attempt −1): the variant it renders with when a task
  names none, and its GPU (:func:`forest.render.variant.capability`);
* exits at once when stdin reaches end-of-file: the service that started it is gone,
  so every lease is void and the work would be redone anyway.

Its stdout and stderr go to the slot's log file; task logs travel as ``log`` reports.
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any


class Channel:
    """Serialised JSON-line writes of reports to the report pipe."""

    def __init__(self, fd: int):
        self.f = os.fdopen(fd, "w", buffering=1, encoding="utf-8")
        self.lock = threading.Lock()

    def send(self, report: Any) -> None:
        """Write ``report`` as one JSON line; exit the worker (75) when the service has gone."""
        line = report.model_dump_json()
        with self.lock:
            try:
                self.f.write(line + "\n")
                self.f.flush()
            except (BrokenPipeError, OSError, ValueError):
                os._exit(75)  # the service is gone


def _read_orders(orders: queue.Queue) -> None:
    try:
        for line in sys.stdin:
            if line.strip():
                orders.put(line)
    except OSError:
        pass
    os._exit(75)


def _warm_up() -> None:
    """Import the renderer and load Mitsuba's CPU variant now, before the first task asks for them."""
    try:
        import forest.library
        import forest.render
        import forest.scatter  # noqa: F401
        from forest.runtime import mitsuba

        mitsuba("scalar_rgb")
    except Exception as e:  # the task that needs it reports the problem
        print(f"warm-up: {type(e).__name__}: {e}", file=sys.stderr, flush=True)


def _report_capability(chan: Channel) -> None:
    """Send the executor what this worker renders with when a task names no variant (:class:`Capability`).

    That choice may run the GPU self-check (a child process, up to a minute, once per machine, driver and Mitsuba),
    so it runs in a thread of its own: tasks are taken meanwhile (one that needs the choice waits for it).
    """
    from .models import Capability

    try:
        from forest.render.variant import capability

        cap = Capability.model_validate({"task_id": -1, "attempt": -1, **capability()})
    except Exception as e:  # the worker list shows no variant; tasks still report their own
        print(f"capability: {type(e).__name__}: {e}", file=sys.stderr, flush=True)
        return
    gpu = f", GPU {cap.gpu}" if cap.gpu else ""
    print(f"renders with {cap.variant} ({cap.variant_reason}){gpu}", file=sys.stderr, flush=True)
    chan.send(cap)


def main(argv: list[str]) -> int:
    """Worker process loop (``argv``: report pipe fd, own folder): run each task order read from stdin and report on
    the pipe, with heartbeats while a task runs; a task's mistakes and errors become ``error`` reports.
    """
    from forest.errors import ForestError, ParameterError

    from .models import Done, Failed, Heartbeat, TaskOrder
    from .runner import TaskContext, execute
    from .scenecache import SceneCache
    from .transfer import BlobStore

    fd, folder = int(argv[0]), Path(argv[1])
    nice = int(os.environ.get("FOREST_WORKER_NICE", "0") or 0)
    if nice:
        try:
            os.nice(nice)
        except OSError:
            pass
    chan = Channel(fd)
    orders: queue.Queue = queue.Queue()
    threading.Thread(target=_read_orders, args=(orders,), daemon=True).start()
    scenes = int(os.environ.get("FOREST_WORKER_SCENES", "1") or 0)
    cache = SceneCache(scenes=scenes, instance_sets=2 * scenes)  # 0: every task loads its scene anew
    blobs = BlobStore(folder)
    current: list[tuple[int, int, float] | None] = [None]

    def beat() -> None:
        while True:
            cur = current[0]
            if cur is not None:
                chan.send(Heartbeat(task_id=cur[0], attempt=cur[1]))
                time.sleep(cur[2])
            else:
                time.sleep(0.2)

    threading.Thread(target=beat, daemon=True).start()
    _warm_up()
    threading.Thread(target=_report_capability, args=(chan,), daemon=True, name="capability").start()
    print(f"worker pid {os.getpid()} ready (folder {folder})", file=sys.stderr, flush=True)
    while True:
        order = TaskOrder.model_validate_json(orders.get())
        spec = order.spec
        tag = f"[job {spec.job_id[:8]} task {spec.index} attempt {order.attempt}]"
        assert order.job_dir is not None, "a local worker writes into the service's job folder"
        job_dir = Path(order.job_dir)

        def inputs(order: TaskOrder = order, job_dir: Path = job_dir) -> Path:
            return blobs.inputs(order.spec.inputs, lambda rel, _sha: job_dir / rel)

        def emit(report: Any, tag: str = tag) -> None:
            if getattr(report, "type", "") == "log":
                print(f"{tag} {report.line}", file=sys.stderr, flush=True)
            chan.send(report)

        ctx = TaskContext(order.task_id, order.attempt, job_dir, inputs, cache, emit)
        current[0] = (order.task_id, order.attempt, order.heartbeat_s)
        chan.send(Heartbeat(task_id=order.task_id, attempt=order.attempt))
        try:
            result = execute(spec, ctx)
            report: Any = Done(task_id=order.task_id, attempt=order.attempt, result=result)
        except ParameterError as e:
            error = blobs.relative(e.message, job_dir)  # files as the job names them
            report = Failed(task_id=order.task_id, attempt=order.attempt, error=error, param=e.field, user=True)
        except ForestError as e:
            error = blobs.relative(str(e), job_dir)
            report = Failed(task_id=order.task_id, attempt=order.attempt, error=error, user=True)
        except MemoryError:
            chan.send(Failed(task_id=order.task_id, attempt=order.attempt, error="out of memory"))
            os._exit(1)
        except Exception as e:
            tb = traceback.format_exc()
            print(f"{tag} crashed:\n{tb}", file=sys.stderr, flush=True)
            report = Failed(
                task_id=order.task_id, attempt=order.attempt, error=f"{type(e).__name__}: {e}", traceback=tb
            )
            cache.clear()  # a crash may leave a loaded scene in a bad state
        current[0] = None
        print(f"{tag} {report.type}", file=sys.stderr, flush=True)
        chan.send(report)


if __name__ == "__main__":
    code = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # do not wait on the heartbeat thread or the renderer's thread pools
