"""Ray: task attempts on a cluster whose nodes share no disk with the service.

Each slot is a long-lived Ray actor (:class:`RayWorker`) with its own working folder on
its own node (a fresh temporary folder, under ``$FOREST_WORKER_DIR`` when set), its own
scene cache and a content-addressed store of the inputs it has fetched.  Nothing in a
task names a path of the service's data folder:

* **inputs go out through Ray's object store** — the service ``ray.put``\\ s each input
  file once per content hash (the refs are kept, least recently used first out, up to
  ``blob_cache_bytes``) and passes the refs with the task; a worker fetches only the
  hashes it does not hold and lays them out under the job-relative names;
* **outputs come back inside the reports** — the preview after each pass, each frame's
  EXR, PNG and thumbnail as soon as the frame is done, and the files of a match or an
  export — through a small reporter actor the driver drains; the dispatcher writes them
  into the job folder.  A frame that reached the service is not lost when its worker is.

While an actor waits for its node (resources to free, a cold start), the executor holds
its task's lease; once it runs, the worker's own heartbeats do.

Resource requests: ``num_cpus`` (``settings.cpus``, default 1) and ``num_gpus``
(``settings.gpus``, default 1 for ``cuda_*`` variants — ``settings.variant``, else the
config's ``[render] variant``, or ``[lookdev] variant`` for a match — so such tasks land
on GPU nodes); an actor keeps its resources while it lives, and an idle actor of another
shape is let go when a task needs a slot of a different one.  An actor that reserved no
GPU hides the node's GPUs from itself, so a task that names no variant renders on the
CPU there; with a GPU reserved (``settings.gpus``) such a task takes the GPU where it
passed forest's self-check (:mod:`forest.render.selfcheck`).  Each actor reports that
choice and its GPU (:meth:`RayWorker.info`) for the worker list.
"""

from __future__ import annotations

import os
import socket
import tempfile
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..models import Exit, Failed, Heartbeat, Log, TaskOrder, TaskSpec
from ..store import TaskRun
from ..transfer import file_sha256
from .base import Executor, WorkerInfo


class RayWorker:
    """One slot: runs task after task in its own folder (a Ray actor; see the module docstring)."""

    def __init__(self, scenes: int = 1, gpus: float = 0.0):
        from ..scenecache import SceneCache
        from ..transfer import BlobStore

        if not gpus:
            # Ray leaves CUDA_VISIBLE_DEVICES alone for an actor that reserved no GPU: hide the node's GPUs, so a
            # task that names no variant renders on the CPU here (forest.runtime.cuda_available) rather than on a
            # GPU reserved by another actor.
            os.environ["CUDA_VISIBLE_DEVICES"] = ""
        base = os.environ.get("FOREST_WORKER_DIR") or None
        if base:
            Path(base).mkdir(parents=True, exist_ok=True)
        self.root = Path(tempfile.mkdtemp(prefix="forest-ray-worker-", dir=base))
        self.cache = SceneCache(scenes=scenes, instance_sets=2 * scenes)
        self.blobs = BlobStore(self.root / "store")

    def info(self) -> dict:
        """Where the actor runs and what it renders with: ``{"pid", "host", "folder"}`` and the fields of
        :func:`forest.render.variant.capability` (``variant``, ``variant_reason``, ``gpu``, ``gpu_memory_mib``;
        missing when the choice failed).  The choice may run the GPU self-check (up to a minute, once per node,
        driver and Mitsuba) before the actor's first task, while the executor holds that task's lease."""
        out: dict[str, Any] = {"pid": os.getpid(), "host": socket.gethostname(), "folder": str(self.root)}
        try:
            from forest.render.variant import capability

            out.update(capability())
        except Exception as e:
            out["variant_reason"] = f"cannot choose a variant: {type(e).__name__}: {e}"
        return out

    def run(self, order_json: str, blob_refs: dict, reporter: Any) -> Any:
        """Run one attempt (a ``TaskOrder`` as JSON) with its inputs fetched from ``blob_refs``; reports go to
        ``reporter`` (heartbeats from a thread of their own) and the result, ``Done`` or ``Failed``, is returned.
        """
        import traceback

        import ray

        from forest.errors import ForestError, ParameterError

        from ..models import Done, Heartbeat
        from ..runner import TaskContext, execute

        order = TaskOrder.model_validate_json(order_json)
        spec = order.spec
        job_dir = self.root / "jobs" / spec.job_id
        stop = threading.Event()

        def emit(report: Any) -> None:
            reporter.put.remote(report)

        def beat() -> None:
            while not stop.is_set():
                emit(Heartbeat(task_id=order.task_id, attempt=order.attempt))
                stop.wait(order.heartbeat_s)

        def fetch(_rel: str, sha: str) -> Path:
            return self.blobs.put_bytes(sha, ray.get(blob_refs[sha]))

        def inputs() -> Path:
            return self.blobs.inputs(spec.inputs, fetch)

        threading.Thread(target=beat, daemon=True).start()
        ctx = TaskContext(order.task_id, order.attempt, job_dir, inputs, self.cache, emit, ship=True)
        ctx.log(f"on {socket.gethostname()} pid {os.getpid()} in {self.root}")
        try:
            result: Any = Done(task_id=order.task_id, attempt=order.attempt, result=execute(spec, ctx))
        except ParameterError as e:
            error = self.blobs.relative(e.message, job_dir)  # files as the job names them
            result = Failed(task_id=order.task_id, attempt=order.attempt, error=error, param=e.field, user=True)
        except ForestError as e:
            error = self.blobs.relative(str(e), job_dir)
            result = Failed(task_id=order.task_id, attempt=order.attempt, error=error, user=True)
        except Exception as e:
            self.cache.clear()
            result = Failed(
                task_id=order.task_id,
                attempt=order.attempt,
                error=f"{type(e).__name__}: {e}",
                traceback=traceback.format_exc(),
            )
        finally:
            stop.set()
        ray.get(reporter.ping.remote())  # every report sent above has reached the reporter
        return result


class Reporter:
    """Collects reports from every worker until the driver drains them (a Ray actor)."""

    def __init__(self) -> None:
        self.items: list[Any] = []

    def put(self, item: Any) -> None:
        """Keep one report until the next :meth:`drain`."""
        self.items.append(item)

    def ping(self) -> bool:
        """True, once every report sent before it has arrived (an actor's calls run in order)."""
        return True

    def drain(self) -> list[Any]:
        """The reports received since the last drain, in order."""
        items, self.items = self.items, []
        return items


@dataclass
class _Actor:
    index: int
    handle: Any
    shape: tuple[float, float]
    info_ref: Any = None
    info: dict = field(default_factory=dict)
    current: tuple[int, int] | None = None
    ref: Any = None
    job_id: str | None = None
    task: int | None = None
    since: float = field(default_factory=time.time)
    tasks_done: int = 0
    scenes: set[str] = field(default_factory=set)


class RayExecutor(Executor):
    """``slots`` Ray actors at most, created on demand (see the module docstring)."""

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        *,
        slots: int = 1,
        jobs: str | Path,
        heartbeat_s: float = 1.0,
        scenes: int = 1,
        init_kwargs: dict | None = None,
        blob_cache_bytes: int = 2 * 2**30,
    ):
        try:
            import ray
        except ImportError:
            from forest.errors import ParameterError

            raise ParameterError("executor", "ray is not installed (pip install 'forest[ray]')") from None
        self.ray = ray
        self.max_slots = max(0, int(slots))
        self.jobs = Path(jobs)
        self.heartbeat_s = heartbeat_s
        self.scenes = scenes
        self.blob_cache_bytes = blob_cache_bytes
        self.started_ray = False
        if not ray.is_initialized():
            kwargs = dict(init_kwargs or {})
            kwargs.setdefault("include_dashboard", False)
            kwargs.setdefault("logging_level", "warning")
            kwargs.setdefault("log_to_driver", False)
            if address:
                for k in ("num_cpus", "num_gpus", "object_store_memory", "include_dashboard", "_temp_dir"):
                    kwargs.pop(k, None)
            ray.init(address=address, **kwargs)
            self.started_ray = True
        self.reporter = ray.remote(num_cpus=0)(Reporter).remote()
        self.actor_cls = ray.remote(RayWorker)
        self._actors: list[_Actor] = []
        self._next = 0
        self._blobs: OrderedDict[str, tuple[Any, int]] = OrderedDict()
        self._drain: Any = None  # the reporter's drain in flight
        self._covered: list[Any] = []  # finished runs whose last reports that drain carries
        self._waiting: list[Any] = []  # finished runs seen after it was issued
        self.lock = threading.Lock()

    # -- state -----------------------------------------------------------------------
    @property
    def slots(self) -> int:
        """The most actors the executor keeps at once."""
        return self.max_slots

    def capacity(self) -> int:
        """Slots without a running attempt (idle actors and ones not yet created)."""
        with self.lock:
            return self.max_slots - sum(a.current is not None for a in self._actors)

    def active(self) -> set[tuple[int, int]]:
        """The attempts the actors run."""
        with self.lock:
            return {a.current for a in self._actors if a.current is not None}

    def workers(self) -> list[WorkerInfo]:
        """Each actor: busy, idle or starting (waiting for its node), with its host, attempt and counts."""
        with self.lock:
            return [
                WorkerInfo(
                    name=f"ray-{a.index}",
                    executor=self.name,
                    state="busy" if a.current else ("idle" if a.info else "starting"),
                    pid=a.info.get("pid"),
                    host=a.info.get("host"),
                    folder=a.info.get("folder"),
                    task_id=a.current[0] if a.current else None,
                    attempt=a.current[1] if a.current else None,
                    job_id=a.job_id if a.current else None,
                    task=a.task if a.current else None,
                    since=a.since,
                    tasks_done=a.tasks_done,
                    scenes=len(a.scenes),
                    variant=a.info.get("variant"),
                    variant_reason=a.info.get("variant_reason"),
                    gpu=a.info.get("gpu"),
                    gpu_memory_mib=a.info.get("gpu_memory_mib"),
                )
                for a in self._actors
            ]

    @staticmethod
    def resources(spec: TaskSpec) -> dict[str, float]:
        """Ray resource request: ``cpus`` CPUs (default 1), a GPU for ``cuda_*`` variants."""
        gpus = spec.resources.gpus
        if gpus is None:
            gpus = 1.0 if str(spec.variant or "").startswith("cuda") else 0.0
        cpus = spec.resources.cpus if spec.resources.cpus is not None else 1.0
        return {"num_cpus": float(cpus), "num_gpus": float(gpus)}

    # -- inputs ---------------------------------------------------------------------------
    def _blob_refs(self, run: TaskRun) -> dict[str, Any]:
        """Object refs of the task's inputs, put once per content hash."""
        refs = {}
        job_dir = self.jobs / run.job_id
        for rel, sha in run.spec.inputs.items():
            hit = self._blobs.get(sha)
            if hit is None:
                path = job_dir / rel
                if file_sha256(path) != sha:
                    raise OSError(f"{rel}: changed since the job was submitted")
                data = path.read_bytes()
                hit = (self.ray.put(data), len(data))
                self._blobs[sha] = hit
            self._blobs.move_to_end(sha)
            refs[sha] = hit[0]
        total = sum(size for _, size in self._blobs.values())
        while total > self.blob_cache_bytes and len(self._blobs) > len(refs):
            _, (_, size) = self._blobs.popitem(last=False)
            total -= size
        return refs

    # -- starting ---------------------------------------------------------------------
    def _actor_for(self, shape: tuple[float, float], scene: str) -> _Actor:
        idle = [a for a in self._actors if a.current is None]
        fits = [a for a in idle if a.shape == shape]
        for group in ([a for a in fits if scene in a.scenes], fits):
            if group:
                return group[0]
        if len(self._actors) >= self.max_slots:  # let an idle actor of another shape go
            old = idle[0]
            self._actors.remove(old)
            self.ray.kill(old.handle, no_restart=True)
        handle = self.actor_cls.options(num_cpus=shape[0], num_gpus=shape[1], max_restarts=0, max_concurrency=1).remote(
            self.scenes, shape[1]
        )
        actor = _Actor(index=self._next, handle=handle, shape=shape, info_ref=handle.info.remote())  # type: ignore[attr-defined]
        self._next += 1
        self._actors.append(actor)
        return actor

    def start(self, run: TaskRun) -> str:
        """Run the attempt on an idle actor of its resource shape (one with the scene loaded first), else on a
        new one; returns ``ray:<n>``.
        """
        res = self.resources(run.spec)
        order = TaskOrder(
            task_id=run.task_id, attempt=run.attempt, spec=run.spec, job_dir=None, heartbeat_s=self.heartbeat_s
        )
        with self.lock:
            refs = self._blob_refs(run)
            actor = self._actor_for((res["num_cpus"], res["num_gpus"]), run.spec.scene_key)
            actor.ref = actor.handle.run.remote(order.model_dump_json(), refs, self.reporter)
            actor.current = (run.task_id, run.attempt)
            actor.job_id, actor.task, actor.since = run.job_id, run.index, time.time()
            actor.scenes.add(run.spec.scene_key)
            return f"ray:{actor.index}"

    # -- the dispatcher's loop ----------------------------------------------------------
    def poll(self, timeout: float) -> list[Any]:
        """Reports within ``timeout`` seconds: the reporter's drain, then the results and exits of the runs it covers;
        heartbeats for attempts whose actor still waits for its node.
        """
        ray = self.ray
        with self.lock:
            running = [a for a in self._actors if a.current is not None]
            pending_info = [a for a in self._actors if a.info_ref is not None]
        for a in pending_info:
            ready, _ = ray.wait([a.info_ref], timeout=0)
            if ready:
                try:
                    a.info = ray.get(a.info_ref)
                except Exception:
                    a.info = {}
                a.info_ref = None
        # an actor still waiting for its node (resources, a cold start) holds its task's lease
        finished: list[Any] = [
            Heartbeat(task_id=a.current[0], attempt=a.current[1])
            for a in running
            if a.info_ref is not None and a.current is not None
        ]
        if running:
            ready, _ = ray.wait([a.ref for a in running], num_returns=len(running), timeout=0)
            ready_set = set(ready)
            for a in running:
                if a.ref not in ready_set or a.current is None:
                    continue
                task_id, attempt = a.current
                try:
                    finished.append(ray.get(a.ref))
                    code = 0
                except Exception as e:
                    finished.append(Log(task_id=task_id, attempt=attempt, line=f"ray worker lost: {type(e).__name__}"))
                    code = -9
                    with self.lock:
                        if a in self._actors:
                            self._actors.remove(a)
                with self.lock:
                    a.current, a.ref, a.since = None, None, time.time()
                    a.tasks_done += 1
                finished.append(Exit(task_id=task_id, attempt=attempt, code=code))
        # A run pings the reporter before it returns, so its last reports are in the first drain
        # issued after the run was seen finished: its result waits for that drain (reports first,
        # then the result).  A drain not back yet is kept, never dropped with what it carries.
        self._waiting.extend(finished)
        out: list[Any] = []
        if self._drain is None and (running or self._waiting):
            self._drain = self.reporter.drain.remote()  # type: ignore[attr-defined]
            self._covered, self._waiting = self._waiting, []
        ready = ray.wait([self._drain], timeout=max(timeout, 0.0))[0] if self._drain is not None else []
        if ready:
            try:
                out.extend(ray.get(self._drain))
            except Exception as e:
                out.append(Log(task_id=-1, attempt=-1, line=f"reporter lost: {type(e).__name__}"))
            out.extend(self._covered)
            self._drain, self._covered = None, []
        if not out:
            time.sleep(min(timeout, 0.05))
        return out

    def kill(self, task_id: int, attempt: int) -> None:
        """Kill the actor running this attempt (its run then ends as a lost worker)."""
        with self.lock:
            actor = next((a for a in self._actors if a.current == (task_id, attempt)), None)
        if actor is not None:
            try:
                self.ray.kill(actor.handle, no_restart=True)
            except Exception:
                pass

    def close(self) -> None:
        """Kill every actor, and shut Ray down if this executor started it."""
        with self.lock:
            actors, self._actors = self._actors, []
        for a in actors:
            try:
                self.ray.kill(a.handle, no_restart=True)
            except Exception:
                pass
        if self.started_ray:
            try:
                self.ray.shutdown()
            except Exception:
                pass
