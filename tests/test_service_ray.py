"""The Ray executor: workers that share no folder with the service, against a local Ray started here."""

from __future__ import annotations

import hashlib
import shutil
import tempfile
from pathlib import Path

import httpx
import pytest

from test_service_support import ServerThread, read_events, tiny_config, wait_job

ray = pytest.importorskip("ray")

from forest.service.app import ServiceConfig, create_app
from forest.service.executors import RayExecutor
from forest.service.models import Resources, TaskSpec


def spec(**kw) -> TaskSpec:
    return TaskSpec(job_id="0" * 32, kind="render", index=0, config="x = 1", output="out/render.exr", **kw)


def test_resource_requests_send_gpu_jobs_to_gpu_nodes():
    assert RayExecutor.resources(spec(variant="cuda_ad_rgb")) == {"num_cpus": 1.0, "num_gpus": 1.0}
    assert RayExecutor.resources(spec(variant="scalar_rgb")) == {"num_cpus": 1.0, "num_gpus": 0.0}
    assert RayExecutor.resources(spec(resources=Resources(cpus=4))) == {"num_cpus": 4.0, "num_gpus": 0.0}


def test_two_ray_workers_without_a_shared_folder_render_a_four_frame_job(tmp_path):
    from test_service_api import png_bytes

    ray_tmp = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # Ray's socket paths must stay short
    workers_root = tmp_path / "elsewhere"  # each Ray worker makes its own folder in here
    data = tmp_path / "data"
    cfg = ServiceConfig(
        data_dir=data,
        workers=2,
        executor="ray",
        seed_examples=False,
        ray_init={
            "num_cpus": 2,
            "num_gpus": 0,
            "include_dashboard": False,
            "object_store_memory": 80 * 2**20,
            "_temp_dir": ray_tmp,
            "runtime_env": {"env_vars": {"FOREST_WORKER_DIR": str(workers_root)}},
        },
    )
    try:
        with ServerThread(create_app(cfg)) as srv, httpx.Client(base_url=srv.url, timeout=60) as c:
            assert c.get("/health").json()["executor"] == "ray"
            # an input the workers can only get through Ray's object store
            mask = png_bytes(16, 16)
            assert c.put("/assets/maps/mask.png", content=mask).status_code == 201
            text = tiny_config().replace("[scatter]", '[maps]\npresence = "maps/mask.png"\n[scatter]')
            r = c.post("/jobs", json={"kind": "flythrough", "config": text, "settings": {"frames": "1-4"}})
            assert r.status_code == 202, r.text
            jid = r.json()["id"]
            events = read_events(c, jid, timeout=240)
            job = c.get(f"/jobs/{jid}").json()
            assert job["state"] == "succeeded", [(t["state"], t["error"]) for t in job["tasks"]]
            assert sorted(d["frame"] for k, d in events if k == "frame") == [1, 2, 3, 4]
            assert any(k == "progress" and "preview" in d for k, d in events)
            job = wait_job(c, jid)
            assert {t["worker"] for t in job["tasks"]} == {"ray:0", "ray:1"}

            workers = c.get("/workers").json()["workers"]
            folders = [Path(w["folder"]) for w in workers]
            assert len(workers) == 2 and len({w["pid"] for w in workers}) == 2 and len(set(folders)) == 2
            assert sum(w["tasks_done"] for w in workers) == 4 and all(w["tasks_done"] >= 1 for w in workers)
            for folder in folders:
                assert folder.parent == workers_root and data not in folder.parents
                # the input arrived by content hash, and the worker rendered its frames in its own folder
                assert (folder / "store" / "blobs" / hashlib.sha256(mask).hexdigest()).read_bytes() == mask
                mine = sorted((folder / "jobs" / jid / "out").glob("frame_*.exr"))
                assert mine
                for p in mine:  # the service holds the same bytes, shipped back through Ray
                    assert (data / "jobs" / jid / "out" / p.name).read_bytes() == p.read_bytes()
            ours = sorted(p.name for p in (data / "jobs" / jid / "out").iterdir())
            assert ours == [f"frame_{f:04d}.{e}" for f in range(1, 5) for e in ("exr", "png")]
            frames = c.get(f"/jobs/{jid}/frames").json()
            assert [f["state"] for f in frames] == ["done"] * 4 and c.get(frames[3]["thumb"]).status_code == 200

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
