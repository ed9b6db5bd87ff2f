"""Workers say what they render with — the variant (the GPU only where it passed forest's self-check) and their
GPU — and only tasks that render in cuda_ad_rgb reserve a GPU on Ray.

CPU only: the GPU and its self-check are faked (``fake_gpu`` in conftest.py), Ray is not started.
"""

from __future__ import annotations

import json
import sys
import textwrap
import threading
import time
from types import SimpleNamespace

import httpx
import numpy as np
import pytest

from test_service_support import ServerThread, tiny_config

pytest.importorskip("fastapi")

from forest.runtime import find_llvm
from forest.service import app as app_module
from forest.service.app import ServiceConfig, create_app
from forest.service.executors.local import LocalExecutor
from forest.service.executors.ray import RayExecutor, RayWorker, _Actor
from forest.service.models import Capability
from forest.service.worker import _report_capability

PASSED = "GPU found and its self-check passed: forest_path on the GPU"


class Chan:
    """The worker's report pipe, kept in a list."""

    def __init__(self):
        self.sent = []

    def send(self, report):
        self.sent.append(report)


def test_a_worker_reports_its_gpu_and_that_it_passed(fake_gpu):
    chan = Chan()
    _report_capability(chan)
    assert chan.sent == [
        Capability(
            task_id=-1,
            attempt=-1,
            variant="cuda_ad_rgb",
            variant_reason=PASSED,
            gpu="NVIDIA H100 80GB HBM3",
            gpu_memory_mib=81559,
        )
    ]


def test_a_worker_whose_gpu_failed_its_self_check_renders_on_the_cpu_and_says_why(fake_gpu):
    fake_gpu.outcome = lambda: np.full((36, 64, 4), np.nan)
    chan = Chan()
    _report_capability(chan)
    [cap] = chan.sent
    assert cap.variant == "llvm_ad_rgb" and cap.gpu == "NVIDIA H100 80GB HBM3" and cap.gpu_memory_mib == 81559
    assert cap.variant_reason.startswith("GPU self-check failed: 2304 of 2304 pixels are not finite")
    assert cap.variant_reason.endswith("force the GPU with --variant cuda_ad_rgb")


STAND_IN = """\
#!{python}
# A stand-in worker: reports a GPU's capability on the report pipe, as forest.service.worker does, then waits.
import json, os, sys
with os.fdopen(int(sys.argv[3]), "w") as reports:
    reports.write(json.dumps({cap}) + "\\n")
    reports.flush()
    sys.stdin.read()
"""


def test_the_worker_list_shows_what_each_worker_renders_with(tmp_path, monkeypatch):
    cap = {
        "type": "capability",
        "task_id": -1,
        "attempt": -1,
        "variant": "cuda_ad_rgb",
        "variant_reason": PASSED,
        "gpu": "NVIDIA H100 80GB HBM3",
        "gpu_memory_mib": 81559,
    }
    worker = tmp_path / "worker"
    worker.write_text(STAND_IN.format(python=sys.executable, cap=cap))
    worker.chmod(0o755)

    def executor(cfg, datadir):
        return LocalExecutor(cfg.workers, root=datadir.workers, jobs=datadir.jobs, python=str(worker))

    monkeypatch.setattr(app_module, "make_executor", executor)
    app = create_app(ServiceConfig(data_dir=tmp_path / "data", workers=1, dispatch=False, seed_examples=False))
    with ServerThread(app) as srv, httpx.Client(base_url=srv.url, timeout=30) as c:
        deadline = time.monotonic() + 30
        while True:
            [w] = c.get("/workers").json()["workers"]
            if w["variant"] is not None or time.monotonic() > deadline:
                break
            time.sleep(0.05)
        assert {k: w[k] for k in ("state", "variant", "variant_reason", "gpu", "gpu_memory_mib")} == {
            "state": "idle",
            "variant": "cuda_ad_rgb",
            "variant_reason": PASSED,
            "gpu": "NVIDIA H100 80GB HBM3",
            "gpu_memory_mib": 81559,
        }
        # the page's worker table has the column, filled from these fields
        assert "<th>renders with</th>" in c.get("/").text and "w.gpu_memory_mib" in c.get("/static/app.js").text


def test_a_real_worker_without_a_gpu_reports_the_cpu(tmp_path, monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")  # no GPU for it, whatever this machine has
    ex = LocalExecutor(1, root=tmp_path / "workers", jobs=tmp_path / "jobs")
    try:
        deadline = time.monotonic() + 120
        while (w := ex.workers()[0]).variant is None and time.monotonic() < deadline:
            time.sleep(0.1)
    finally:
        ex.close()
    cpu = "llvm_ad_rgb" if find_llvm() is not None else "scalar_rgb"
    assert w.variant == cpu and w.gpu is None and w.gpu_memory_mib is None
    assert w.variant_reason and w.variant_reason.startswith(("no GPU", "no LLVM 19"))


# -- Ray ---------------------------------------------------------------------------------------------------------


def test_a_ray_actor_without_a_gpu_hides_the_nodes_and_renders_on_the_cpu(fake_gpu, monkeypatch, tmp_path):
    monkeypatch.setenv("FOREST_WORKER_DIR", str(tmp_path))
    fake_gpu.outcome = lambda: pytest.fail("an actor without a GPU runs no GPU self-check")
    info = RayWorker(1, gpus=0.0).info()
    assert info["variant"] == "llvm_ad_rgb" and info["variant_reason"].startswith("no GPU")
    assert info["gpu"] is None and info["gpu_memory_mib"] is None and info["pid"] and info["folder"]
    assert not fake_gpu.calls


def test_a_ray_actor_with_a_gpu_reports_it_and_the_worker_list_shows_it(fake_gpu, monkeypatch, tmp_path):
    monkeypatch.setenv("FOREST_WORKER_DIR", str(tmp_path))
    info = RayWorker(1, gpus=1.0).info()
    assert (info["variant"], info["gpu"], info["gpu_memory_mib"]) == ("cuda_ad_rgb", "NVIDIA H100 80GB HBM3", 81559)
    assert len(fake_gpu.calls) == 1
    ex = object.__new__(RayExecutor)  # its bookkeeping only: no Ray
    ex.lock = threading.Lock()
    ex._actors = [_Actor(index=0, handle=None, shape=(1.0, 1.0), info=info)]
    [w] = ex.workers()
    assert (w.state, w.variant, w.variant_reason, w.gpu, w.gpu_memory_mib) == (
        "idle",
        "cuda_ad_rgb",
        PASSED,
        "NVIDIA H100 80GB HBM3",
        81559,
    )


def test_ray_actors_reserve_and_are_told_their_gpus():
    made = []

    class ActorClass:
        def options(self, **kw):
            def remote(*args):
                made.append((kw["num_cpus"], kw["num_gpus"], args))
                return SimpleNamespace(info=SimpleNamespace(remote=lambda: None))

            return SimpleNamespace(remote=remote)

    ex = object.__new__(RayExecutor)
    ex.actor_cls, ex._actors, ex._next, ex.max_slots, ex.scenes = ActorClass(), [], 0, 2, 1
    ex._actor_for((1.0, 1.0), "scene a")
    ex._actor_for((2.0, 0.0), "scene b")
    assert made == [(1.0, 1.0, (1, 1.0)), (2.0, 0.0, (1, 0.0))]


def test_match_jobs_reserve_a_gpu_for_lookdevs_cuda_variant_and_the_service_runs_no_self_check(fake_gpu, tmp_path):
    from test_service_api import png_bytes

    fake_gpu.outcome = lambda: pytest.fail("the service itself never runs the GPU self-check")
    app = create_app(ServiceConfig(data_dir=tmp_path / "data", workers=0, dispatch=False, seed_examples=False))
    with ServerThread(app) as srv, httpx.Client(base_url=srv.url, timeout=30) as c:
        if not c.get("/health").json()["capabilities"]["match"]:
            pytest.skip("look-dev is not installed")
        assert c.put("/assets/ref.png", content=png_bytes(32, 24)).status_code == 201
        lookdev_cuda = tiny_config() + textwrap.dedent("""
            [lookdev]
            variant = "cuda_ad_rgb"
        """)
        cases = [
            ("match", tiny_config(), {"reference": "ref.png"}, None),  # the worker chooses: no GPU reserved
            ("match", lookdev_cuda, {"reference": "ref.png"}, 1.0),
            ("match", tiny_config(), {"reference": "ref.png", "variant": "cuda_ad_rgb"}, 1.0),
            ("render", lookdev_cuda, {}, None),  # [render] variant = "scalar_rgb" decides a render
            ("render", tiny_config(), {"variant": "cuda_ad_rgb"}, 1.0),
        ]
        for kind, config, settings, gpus in cases:
            r = c.post("/jobs", json={"kind": kind, "config": config, "settings": settings})
            assert r.status_code == 202, r.text
            task = app.state.service.store.get_task(r.json()["id"], 0)
            spec = task["spec"] if isinstance(task["spec"], dict) else json.loads(task["spec"])
            assert spec["resources"]["gpus"] == gpus, (kind, settings)
    assert not fake_gpu.calls
