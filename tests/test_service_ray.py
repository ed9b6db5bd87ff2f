"""The Ray executor: the same jobs as Ray tasks, against a local Ray started here."""

from __future__ import annotations

import shutil
import tempfile

import httpx
import pytest

from test_service_support import ServerThread, read_events, tiny_config, wait_job

ray = pytest.importorskip("ray")

from forest.service.app import ServiceConfig, create_app
from forest.service.executors import RayExecutor


def test_resource_requests_send_gpu_jobs_to_gpu_nodes():
    assert RayExecutor.resources({"variant": "cuda_ad_rgb"}) == {"num_cpus": 1.0, "num_gpus": 1.0}
    assert RayExecutor.resources({"variant": "scalar_rgb"}) == {"num_cpus": 1.0, "num_gpus": 0.0}
    assert RayExecutor.resources({"variant": None, "resources": {"cpus": 4}}) == {"num_cpus": 4.0, "num_gpus": 0.0}


def test_jobs_run_as_ray_tasks(tmp_path):
    ray_tmp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # Ray's socket paths must stay short
    cfg = ServiceConfig(
        data_dir=tmp_path / "data",
        workers=1,
        executor="ray",
        ray_init={
            "num_cpus": 1,
            "num_gpus": 0,
            "include_dashboard": False,
            "object_store_memory": 80 * 2**20,
            "_temp_dir": ray_tmp,
        },
    )
    try:
        with ServerThread(create_app(cfg)) as srv, httpx.Client(base_url=srv.url, timeout=60) as c:
            assert c.get("/health").json()["executor"] == "ray"
            r = c.post(
                "/jobs",
                json={
                    "kind": "flythrough",
                    "config": tiny_config(),
                    "settings": {"frames": "1-2", "frames_per_task": 1},
                },
            )
            assert r.status_code == 202, r.text
            events = read_events(c, r.json()["id"], timeout=180)
            assert [d["state"] for k, d in events if k == "state"][-1] == "succeeded", events
            assert any(k == "progress" for k, _ in events)
            job = wait_job(c, r.json()["id"])
            assert all(t["worker"].startswith("ray:") for t in job["tasks"])
            res = c.get(f"/jobs/{job['id']}/result").json()
            assert sorted(o["path"] for o in res["outputs"] if o["path"].endswith(".png")) == [
                "out/frame_0001.png",
                "out/frame_0002.png",
            ]
            # a cuda job asks Ray for a GPU; this local Ray has none, so it waits, and a cancel ends it
            r = c.post(
                "/jobs", json={"kind": "render", "config": tiny_config(), "settings": {"variant": "cuda_ad_rgb"}}
            )
            if r.status_code == 202:
                jid = r.json()["id"]
                c.post(f"/jobs/{jid}/cancel")
                assert wait_job(c, jid, timeout=30)["state"] == "canceled"
    finally:
        if ray.is_initialized():
            ray.shutdown()
        shutil.rmtree(ray_tmp, ignore_errors=True)
