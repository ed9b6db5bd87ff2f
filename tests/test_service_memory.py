"""A worker checks a render's memory again once its trees are known, as ``forest render`` does after loading its
scene: a render that will not fit fails with the CLI's one line and leaves no output, rather than a worker killed
for memory."""

from __future__ import annotations

import re

import httpx
import pytest

from forest import preflight
from forest.errors import ForestError
from forest.memory import Room
from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits
from forest.service.models import Log, TaskSpec
from forest.service.runner import TaskContext, execute
from forest.service.scenecache import SceneCache

from test_service_support import ServerThread, tiny_config, wait_job

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

#: What submission checks, the image alone (no trees yet): the tiny scene's 32×24 pixels at 2 spp in scalar_rgb.
IMAGE_ONLY = preflight.render_estimate(32, 24, 2, 0, "scalar_rgb").memory
#: A room the image fits and its trees (with their species' triangles) do not.
ROOM = IMAGE_ONLY + 4 * 2**20
REFUSED = re.compile(
    r"^config: scatter\.count: a 32x24 render of \d+ trees needs about \d+\.\d MiB, \d+\.\d MiB available; "
    r"even a small image does not fit: "
)


def run_task(tmp_path, spec: TaskSpec) -> tuple[list, object]:
    """Run ``spec`` in this process as a worker does; (its reports, its result or the ForestError it raised)."""
    job_dir = tmp_path / "job"
    reports: list = []
    ctx = TaskContext(1, 1, job_dir, lambda: job_dir, SceneCache(scenes=1, instance_sets=2), reports.append)
    try:
        return reports, execute(spec, ctx)
    except ForestError as e:
        return reports, e


def spec_of(config: str, **fields) -> TaskSpec:
    return TaskSpec(
        job_id="0" * 32, kind="render", index=0, config=config, output="out/render.exr", frames=(1,), **fields
    )


def test_the_worker_refuses_a_render_its_room_cannot_hold(tmp_path, monkeypatch):
    """The worker's own room (cgroup-aware, here made small) against the whole render: the CLI's line, no file."""
    monkeypatch.delenv("FOREST_MEMORY_GB", raising=False)
    monkeypatch.setattr(preflight, "memory_room", lambda: Room(ROOM))
    _reports, error = run_task(tmp_path, spec_of(tiny_config()))
    assert isinstance(error, ForestError), error
    assert REFUSED.match(str(error)) and "\n" not in str(error), error
    assert f"{preflight.format_bytes(ROOM)} available" in str(error)
    assert not [p for p in (tmp_path / "job").rglob("*") if p.is_file()]
    # a setting that gave the trees is named as the request names it
    _reports, error = run_task(tmp_path, spec_of(tiny_config(), overrides={"scatter.count": 300}))
    assert str(error).startswith("settings.count: a 32x24 render of "), error


def test_the_service_stated_room_binds_when_smaller(tmp_path, monkeypatch):
    """``spec.memory_bytes`` (the service's ``Limits.worker_memory_bytes``) binds where it is below the worker's
    room; a room that holds the render renders it, with the estimate in the task's log."""
    monkeypatch.delenv("FOREST_MEMORY_GB", raising=False)
    monkeypatch.setattr(preflight, "memory_room", lambda: Room(64 * 2**30))
    _reports, error = run_task(tmp_path, spec_of(tiny_config(), memory_bytes=ROOM))
    assert isinstance(error, ForestError) and REFUSED.match(str(error)), error
    # a room that holds the image, the trees and their prototypes' triangles (scalar_rgb loads each once per
    # colour-jitter bin: about 0.5 GiB for the broadleaf's)
    reports, result = run_task(tmp_path, spec_of(tiny_config(), memory_bytes=IMAGE_ONLY + 800 * 2**20))
    assert not isinstance(result, Exception), result
    lines = [r.line for r in reports if isinstance(r, Log)]
    assert any(
        re.match(r"render: 1 frame 32x24 at 2 spp, \d+ trees: about .* of 1\.\d GiB available", s) for s in lines
    )
    assert (tmp_path / "job" / "out" / "render.exr").is_file()


def test_a_job_over_the_workers_room_fails_with_one_line_and_no_output(tmp_path):
    """A real job through the service and a local worker process: the image alone fits the stated room, so
    submission takes it; the worker, with the trees scattered, fails it with the CLI's line before any output."""
    data = tmp_path / "data"
    cfg = ServiceConfig(data_dir=data, workers=1, seed_examples=False, limits=Limits(worker_memory_bytes=ROOM))
    with ServerThread(create_app(cfg)) as srv, httpx.Client(base_url=srv.url, timeout=30) as c:
        r = c.post("/jobs", json={"kind": "render", "config": tiny_config()})
        assert r.status_code == 202, r.text
        job = wait_job(c, r.json()["id"], timeout=180)
        assert job["state"] == "failed", job
        error = job["tasks"][0]["error"]
        assert REFUSED.match(error) and "\n" not in error, error
        assert job["tasks"][0]["attempt"] == 1  # a mistake in the job, not retried
        assert c.get(f"/jobs/{job['id']}/result").status_code == 409
        job_dir = data / "jobs" / job["id"]
        assert not list(job_dir.glob("out/**/*.*")) and not list(job_dir.glob("preview/*")), list(job_dir.rglob("*"))
