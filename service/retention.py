"""What the service keeps, and for how long.

* **Job records and events** — finished jobs are forgotten by the store after
  ``max_age_s`` or beyond the newest ``max_jobs``; the events of a finished job (the
  replay log of its live stream) after ``events_max_age_s``.  A job's folder is not
  deleted with its record: at the end of every job its view is written to ``job.json``
  in the folder (:func:`write_manifest`), so a forgotten job's outputs are still listed
  and served (``archived``) until the user deletes them.
* **Outputs** — kept until the user deletes the job, or until the job folders together
  exceed ``output_quota_bytes``: then the outputs (``out/``, ``thumbs/``, ``preview/``
  and cached downloads) of the oldest finished jobs go first, until the total fits.
  Logs, config and ``job.json`` stay.  Running and queued jobs are never touched.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from .assets import DataDir
from .store import TERMINAL, Store
from .views import frame_views, job_view

log = logging.getLogger("forest.service")

OUTPUT_DIRS = ("out", "thumbs", "preview", ".downloads")


@dataclass(frozen=True)
class Retention:
    """How long finished jobs, their events and their outputs are kept (None: for ever)."""

    max_age_s: float | None = 30 * 86400.0
    max_jobs: int | None = 10_000
    events_max_age_s: float | None = 3600.0
    output_quota_bytes: int | None = None
    interval_s: float = 60.0


def write_manifest(datadir: DataDir, store: Store, job_id: str) -> None:
    """Write a finished job's view (tasks and frames included) to ``job.json`` in its folder."""
    job = store.get_job(job_id, with_tasks=True)
    if job is None or job["state"] not in TERMINAL:
        return
    folder = datadir.job_dir(job_id)
    if not folder.is_dir():
        return
    frames = store.frames(job_id)
    view = job_view(job, tasks=True, frames=frames)
    view["result"] = job.get("result")
    view["frame_list"] = frame_views(job, frames)
    tmp = folder / ".job.json.tmp"
    tmp.write_text(json.dumps(view, indent=1), encoding="utf-8")
    os.replace(tmp, folder / "job.json")


def read_manifest(datadir: DataDir, job_id: str) -> dict | None:
    """The view saved in a job folder (a job the store no longer holds), marked ``archived``."""
    try:
        p = datadir.job_dir(job_id) / "job.json"
        view = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    view["archived"] = True
    return view


def folder_bytes(folder: Path) -> int:
    """Bytes of the files under ``folder`` (links not followed; files that vanish meanwhile count 0)."""
    total = 0
    for dirpath, _, names in os.walk(folder):
        for n in names:
            try:
                total += os.lstat(os.path.join(dirpath, n)).st_size
            except OSError:
                pass
    return total


def delete_outputs(folder: Path) -> None:
    """Delete a job folder's outputs (``out/``, ``thumbs/``, ``preview/``, cached zips); logs and config stay."""
    for name in OUTPUT_DIRS:
        shutil.rmtree(folder / name, ignore_errors=True)


def sweep(store: Store, datadir: DataDir, policy: Retention, now: float | None = None) -> dict:
    """One pass of the policy; returns what it did (for the log and the tests)."""
    now = time.time() if now is None else now
    pruned, events = store.prune(
        max_age_s=policy.max_age_s, max_jobs=policy.max_jobs, events_max_age_s=policy.events_max_age_s, now=now
    )
    freed: list[str] = []
    if policy.output_quota_bytes is not None:
        freed = _enforce_quota(store, datadir, policy.output_quota_bytes)
    if pruned or events or freed:
        log.info(
            "retention: %d jobs forgotten, %d events deleted, outputs of %d jobs deleted",
            len(pruned),
            events,
            len(freed),
        )
    return {"pruned": pruned, "events": events, "outputs_deleted": freed}


def _enforce_quota(store: Store, datadir: DataDir, quota: int) -> list[str]:
    """Delete the outputs of the oldest finished jobs until the job folders fit in ``quota`` bytes."""
    sizes: dict[str, int] = {}
    finished: list[tuple[float, str]] = []
    for folder in datadir.jobs.iterdir():
        if not folder.is_dir():
            continue
        jid = folder.name
        sizes[jid] = folder_bytes(folder)
        job = store.get_job(jid) if len(jid) == 32 else None
        if job is not None:
            if job["state"] in TERMINAL and not job.get("outputs_deleted"):
                finished.append((job["finished"] or 0.0, jid))
        elif (folder / "out").exists() or (folder / "thumbs").exists():
            view = read_manifest(datadir, jid) if len(jid) == 32 else None
            finished.append(((view or {}).get("finished") or folder.stat().st_mtime, jid))
    total = sum(sizes.values())
    freed = []
    for _, jid in sorted(finished):
        if total <= quota:
            break
        folder = datadir.jobs / jid
        delete_outputs(folder)
        after = folder_bytes(folder)
        total -= sizes[jid] - after
        freed.append(jid)
        if store.get_job(jid) is not None:
            store.mark_outputs_deleted(jid)
            write_manifest(datadir, store, jid)
    return freed
