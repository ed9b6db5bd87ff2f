"""The job service's HTTP API, driven with httpx against a real server and real renders."""

from __future__ import annotations

import asyncio
import os
import signal
import struct
from pathlib import Path

import httpx
import numpy as np
import pytest

from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits

from test_service_support import ServerThread, pid_alive, read_events, tiny_config, wait_for, wait_job

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("service-data")
    cfg = ServiceConfig(
        data_dir=data,
        workers=2,
        limits=Limits(
            max_width=512, max_height=512, max_pixels=512 * 384, max_spp=64, max_trees=5000, max_upload_bytes=200_000
        ),
    )
    with ServerThread(create_app(cfg)) as srv:
        srv.data = data
        with httpx.Client(base_url=srv.url, timeout=30) as client:
            srv.client = client
            yield srv


@pytest.fixture()
def idle(tmp_path):
    """A server that accepts jobs but starts none (no renders)."""
    with ServerThread(create_app(ServiceConfig(data_dir=tmp_path / "data", workers=0, dispatch=False))) as srv:
        with httpx.Client(base_url=srv.url, timeout=30) as client:
            srv.client = client
            yield srv


def png_bytes(w: int = 8, h: int = 6) -> bytes:
    import tempfile

    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.png"
        out = oiio.ImageOutput.create(str(p))
        out.open(str(p), oiio.ImageSpec(w, h, 3, oiio.UINT8))
        out.write_image(np.full((h, w, 3), 200, np.uint8))
        out.close()
        return p.read_bytes()


def read_png(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


# -- a real render, end to end --------------------------------------------------------


def test_render_job_end_to_end(server):
    c = server.client
    # 12 spp: more than a quick look's worth, so the still shows a quick look first, then the final image
    r = c.post(
        "/jobs", json={"kind": "render", "config": tiny_config(), "settings": {"width": 40, "height": 30, "spp": 12}}
    )
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/jobs/{job['id']}"
    assert job["state"] in ("queued", "running") and job["settings"]["width"] == 40

    events = read_events(c, job["id"])
    states = [d["state"] for k, d in events if k == "state"]
    assert states[0] == "queued" and states[-1] == "succeeded" and "running" in states
    progress = [d["progress"] for k, d in events if k == "progress"]
    assert progress and progress == sorted(progress) and progress[-1] == pytest.approx(1.0)
    previews = [(d["message"], d["progress"]) for k, d in events if k == "progress" and "preview" in d]
    assert previews[0][0] == "quick look ready" and previews[0][1] < 0.5 and previews[-1][1] == 1.0
    order = [(k, d.get("state")) for k, d in events if k in ("state", "progress")]
    assert order.index(("state", "running")) < order.index(("progress", None)) < order.index(("state", "succeeded"))

    job = c.get(f"/jobs/{job['id']}").json()
    assert job["state"] == "succeeded" and job["progress"] == 1.0 and job["tasks"][0]["attempt"] == 1
    res = c.get(f"/jobs/{job['id']}/result").json()
    paths = {o["path"] for o in res["outputs"]}
    assert {"out/render.exr", "out/render.png"} <= paths
    assert res["stats"][0]["trees"] > 0 and res["stats"][0]["width"] == 40
    img = c.get(res["image"])
    assert img.status_code == 200 and read_png(img.content) == (40, 30)
    prev = c.get(job["preview"])
    assert prev.status_code == 200 and read_png(prev.content) == (40, 30)
    log = c.get(f"/jobs/{job['id']}/log").text
    assert "started on pid:" in log and "succeeded" in log
    # the job folder is self-contained: the config is kept beside the outputs
    assert (server.data / "jobs" / job["id"] / "config.toml").read_text() == tiny_config()


def test_flythrough_is_split_into_frame_tasks(server):
    c = server.client
    r = c.post(
        "/jobs",
        json={"kind": "flythrough", "config": tiny_config(), "settings": {"frames": "1-3", "frames_per_task": 2}},
    )
    assert r.status_code == 202, r.text
    assert [t["frames"] for t in r.json()["tasks"]] == [[1, 2], [3]]
    job = wait_job(c, r.json()["id"])
    assert job["state"] == "succeeded", job
    res = c.get(f"/jobs/{job['id']}/result").json()
    pngs = sorted(o["path"] for o in res["outputs"] if o["path"].endswith(".png"))
    assert pngs == ["out/frame_0001.png", "out/frame_0002.png", "out/frame_0003.png"]
    assert [s["frames"] for s in res["stats"]] == [[1, 2], [3]]


def test_worker_killed_mid_render_is_requeued_and_finishes(server):
    c = server.client
    r = c.post(
        "/jobs",
        json={
            "kind": "flythrough",
            "config": tiny_config(),
            "settings": {"frames": "1-12", "frames_per_task": 12, "spp": 16},
        },
    )
    jid = r.json()["id"]
    # wait until the worker reports progress from inside the render, then SIGKILL it
    # (twelve frames, so the render is still running when the poll sees it)
    task = wait_for(
        lambda: next(
            (
                t
                for t in c.get(f"/jobs/{jid}").json()["tasks"]
                if t["state"] == "running" and t["message"].startswith(("building", "frame"))
            ),
            None,
        )
    )
    pid = int(task["worker"].split(":")[1])
    os.kill(pid, signal.SIGKILL)
    job = wait_job(c, jid)
    assert job["state"] == "succeeded", job
    assert job["tasks"][0]["attempt"] == 2
    assert not pid_alive(pid)
    log = c.get(f"/jobs/{jid}/log").text
    assert "worker lost" in log and "task queued" in log
    res = c.get(f"/jobs/{jid}/result").json()
    assert len([o for o in res["outputs"] if o["path"].endswith(".exr")]) == 12


def test_cancel_stops_the_worker_process(server):
    c = server.client
    r = c.post(
        "/jobs",
        json={
            "kind": "flythrough",
            "config": tiny_config(),
            "priority": 50,
            "settings": {"frames": "1-8", "frames_per_task": 8},
        },
    )
    jid = r.json()["id"]
    task = wait_for(
        lambda: next(
            (t for t in c.get(f"/jobs/{jid}").json()["tasks"] if t["state"] == "running" and t["worker"]), None
        )
    )
    pid = int(task["worker"].split(":")[1])
    r = c.post(f"/jobs/{jid}/cancel")
    assert r.status_code == 202
    job = wait_job(c, jid)
    assert job["state"] == "canceled" and job["tasks"][0]["state"] == "canceled"
    wait_for(lambda: not pid_alive(pid), timeout=10)
    assert c.post(f"/jobs/{jid}/cancel").status_code == 409
    assert c.get(f"/jobs/{jid}/result").status_code == 409
    # a canceled job can be retried and then finishes
    assert c.post(f"/jobs/{jid}/retry").status_code == 202
    assert wait_job(c, jid)["state"] == "succeeded"


def test_cancel_of_a_queued_job_is_immediate(idle):
    c = idle.client
    jid = c.post("/jobs", json={"kind": "flythrough", "config": tiny_config(), "settings": {"frames": "1-4"}}).json()[
        "id"
    ]
    r = c.post(f"/jobs/{jid}/cancel")
    assert r.status_code == 202 and r.json()["state"] == "canceled"
    assert {t["state"] for t in r.json()["tasks"]} == {"canceled"}
    assert c.post(f"/jobs/{jid}/cancel").status_code == 409
    r = c.post(f"/jobs/{jid}/retry")
    assert r.status_code == 202 and r.json()["state"] == "queued"
    assert c.post(f"/jobs/{jid}/retry").status_code == 409


def test_a_render_error_fails_the_job_once_with_its_message(server):
    c = server.client
    text = tiny_config().replace('model = "shrub"', 'model = "no_such_species"')
    r = c.post("/jobs", json={"kind": "render", "config": text})
    assert r.status_code == 202, r.text
    job = wait_job(c, r.json()["id"])
    assert job["state"] == "failed" and "no_such_species" in job["error"]
    assert job["tasks"][0]["attempt"] == 1  # a user mistake is not retried
    res = c.get(f"/jobs/{job['id']}/result")
    assert res.status_code == 409 and "no_such_species" in res.json()["detail"]
    assert "no_such_species" in c.get(f"/jobs/{job['id']}/log").text


def test_bad_config_fails_cleanly_before_any_job(server):
    c = server.client
    before = c.get("/jobs").json()["counts"]
    cases = [
        ("not = [toml", "invalid TOML"),
        (tiny_config().replace("count = 300", "count = -5"), "scatter.count"),
        (tiny_config().replace('model = "shrub"', 'model = "shrub"\nbogus = 1'), "species[0].bogus"),
        ("colour = 3\n" + tiny_config(), "colour: unknown key"),
        (tiny_config().replace("spp = 2", "spp = 'many'"), "render.spp"),
        ("render = 5\n" + tiny_config().replace("[render]", "[rendering]"), "render"),
    ]
    for text, needle in cases:
        r = c.post("/jobs", json={"kind": "render", "config": text})
        assert r.status_code == 422 and needle in r.json()["detail"], r.text
    assert c.get("/jobs").json()["counts"] == before


@pytest.mark.parametrize(
    "settings, field",
    [
        ({"width": 4000}, "settings.width"),
        ({"spp": 65}, "settings.spp"),
        ({"count": 6000}, "settings.count"),
        ({"width": 512, "height": 512}, "settings.width×height"),
    ],
)
def test_limits_answer_422_naming_the_setting(server, settings, field):
    r = server.client.post("/jobs", json={"kind": "render", "config": tiny_config(), "settings": settings})
    assert r.status_code == 422 and field in r.json()["detail"] and "limit" in r.json()["detail"]


def test_unknown_job_and_bad_request_shapes(server):
    c = server.client
    assert c.get("/jobs/" + "0" * 32).status_code == 404
    assert c.get("/jobs/nope").status_code == 404
    assert c.post("/jobs", json={"kind": "paint", "config": "x"}).status_code == 422
    assert c.post("/jobs", json={"kind": "render", "config": "x", "extra": 1}).status_code == 422
    assert (
        c.post("/jobs", json={"kind": "render", "config": tiny_config(), "settings": {"frames": "1-3"}}).status_code
        == 422
    )


# -- assets ---------------------------------------------------------------------------


def test_uploads_are_checked_and_size_limited(server):
    c = server.client
    ok = c.put("/assets/presence.png", content=png_bytes())
    assert ok.status_code == 201 and ok.json()["width"] == 8 and ok.json()["kind"] == "image"
    assert c.put("/assets/fake.png", content=b"this is not an image").status_code == 415
    assert c.put("/assets/huge.png", content=b"\0" * 200_001).status_code == 413
    assert c.put("/assets/notes.txt", content=b"hello").status_code == 415
    assert c.put("/assets/..png", content=png_bytes()).status_code == 422
    import trimesh

    ply = trimesh.creation.box().export(file_type="ply")
    mesh = c.put("/assets/box.ply", content=ply)
    assert mesh.status_code == 201 and mesh.json()["triangles"] == 12
    assert c.put("/assets/empty.ply", content=b"ply\nformat ascii 1.0\nend_header\n").status_code == 415
    names = {a["name"] for a in c.get("/assets").json()}
    assert {"presence.png", "box.ply"} <= names and "fake.png" not in names
    assert not [p for p in (server.data / "assets").iterdir() if p.name.startswith(".upload")]


def test_config_assets_resolve_inside_the_data_folder_only(server, tmp_path):
    c = server.client
    assert c.put("/assets/mask.png", content=png_bytes(16, 16)).status_code == 201
    outside = tmp_path / "secret.png"
    outside.write_bytes(png_bytes())
    (server.data / "assets" / "link.png").symlink_to(outside)
    for ref, needle in [
        ("../jobs/x.png", "'..'"),
        ("/etc/x.png", "relative"),
        ("~/x.png", "relative"),
        ("link.png", "outside the data folder"),
        ("missing.png", "not found"),
        ("maps\\\\x.png", "relative"),
    ]:
        text = tiny_config().replace("[scatter]", f'[maps]\npresence = "{ref}"\n[scatter]')
        r = c.post("/jobs", json={"kind": "render", "config": text})
        assert r.status_code == 422 and needle in r.json()["detail"] and "maps.presence" in r.json()["detail"], (
            ref,
            r.text,
        )
    text = tiny_config().replace("[scatter]", '[maps]\npresence = "mask.png"\n[scatter]')
    r = c.post("/jobs", json={"kind": "render", "config": text})
    assert r.status_code == 202, r.text
    linked = server.data / "jobs" / r.json()["id"] / "mask.png"
    assert linked.is_file() and linked.read_bytes() == (server.data / "assets" / "mask.png").read_bytes()
    assert wait_job(c, r.json()["id"])["state"] == "succeeded"


def test_match_job_fits_the_look_to_a_reference(server):
    c = server.client
    if not c.get("/health").json()["capabilities"]["match"]:
        pytest.skip("look-dev is not installed")
    assert c.put("/assets/ref.png", content=png_bytes(32, 24)).status_code == 201
    bad = c.post(
        "/jobs", json={"kind": "match", "config": tiny_config(), "settings": {"reference": "ref.png", "mode": "bogus"}}
    )
    assert bad.status_code == 422 and "settings.mode" in bad.json()["detail"]
    r = c.post(
        "/jobs",
        json={
            "kind": "match",
            "config": tiny_config(),
            "settings": {"reference": "ref.png", "iterations": 2, "resolution": 16, "match_spp": 1},
        },
    )
    assert r.status_code == 202, r.text
    job = wait_job(c, r.json()["id"], timeout=120)
    assert job["state"] == "succeeded", job
    res = c.get(f"/jobs/{job['id']}/result").json()
    paths = {o["path"] for o in res["outputs"]}
    assert "out/match.json" in paths and any(p.endswith(".png") for p in paths)
    assert res["stats"][0]["losses"] and c.get(job["preview"]).status_code == 200


def test_match_jobs_need_a_reference_and_the_capability(server):
    c = server.client
    caps = c.get("/health").json()["capabilities"]
    assert caps["render"] and caps["flythrough"]
    r = c.post("/jobs", json={"kind": "match", "config": tiny_config(), "settings": {"reference": "nope.png"}})
    assert r.status_code == 422
    if not caps["match"]:
        assert "not available" in r.json()["detail"]
    else:
        assert "nope.png" in r.json()["detail"]


# -- idempotency, concurrency, auth (no renders) ------------------------------------


def test_idempotency_key_makes_resubmits_safe(idle):
    c = idle.client
    body = {"kind": "render", "config": tiny_config()}
    a = c.post("/jobs", json=body, headers={"Idempotency-Key": "k-1"})
    b = c.post("/jobs", json=body, headers={"Idempotency-Key": "k-1"})
    assert a.status_code == b.status_code == 202
    assert a.json()["id"] == b.json()["id"] and a.headers["location"] == b.headers["location"]
    assert b.headers.get("idempotent-replayed") == "true"
    other = c.post("/jobs", json={**body, "priority": 3}, headers={"Idempotency-Key": "k-1"})
    assert other.status_code == 409
    assert c.get("/jobs").json()["counts"]["queued"] == 1


def test_hundred_concurrent_submissions_all_accounted_for(idle):
    async def main():
        async with httpx.AsyncClient(base_url=idle.url, timeout=60, limits=httpx.Limits(max_connections=100)) as ac:

            async def one(i):
                # 80 distinct jobs, then 20 submissions that are 10 jobs each sent twice
                n = i if i < 80 else 80 + i % 10
                headers = {"Idempotency-Key": f"dup-{n}"} if i >= 80 else {}
                return await ac.post(
                    "/jobs",
                    json={"kind": "render", "config": tiny_config(), "priority": n % 7, "name": f"job {n}"},
                    headers=headers,
                )

            return await asyncio.gather(*(one(i) for i in range(100)))

    rs = asyncio.run(main())
    assert all(r.status_code == 202 for r in rs), [r.text for r in rs if r.status_code != 202][:3]
    ids = [r.json()["id"] for r in rs]
    assert len(set(ids[:80])) == 80 and len(set(ids[80:])) == 10 and not set(ids[:80]) & set(ids[80:])
    listed = idle.client.get("/jobs", params={"limit": 500}).json()
    assert {j["id"] for j in listed["jobs"]} == set(ids) and listed["counts"]["queued"] == 90
    assert sorted(j["name"] for j in listed["jobs"]) == sorted(f"job {n}" for n in range(90))


def test_token_is_required_when_configured(tmp_path):
    app = create_app(ServiceConfig(data_dir=tmp_path / "d", workers=0, dispatch=False, token="s3cret-token"))
    with ServerThread(app) as srv, httpx.Client(base_url=srv.url) as c:
        assert c.get("/jobs").status_code == 401
        assert c.get("/jobs", headers={"Authorization": "Bearer wrong-token"}).status_code == 401
        assert c.get("/jobs", headers={"Authorization": "Bearer s3cret-token"}).status_code == 200
        assert c.get("/jobs", params={"access_token": "s3cret-token"}).status_code == 200
        assert (
            c.post("/jobs", params={"access_token": "s3cret-token"}, json={"kind": "render", "config": "x"}).status_code
            == 401
        )
        assert c.get("/").status_code == 200  # the page itself asks for the token


def test_one_service_per_data_folder(server):
    import subprocess

    from test_service_support import FOREST

    r = subprocess.run(
        [str(FOREST), "serve", "--data", str(server.data), "--port", "0"], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and "another forest service" in r.stderr


def test_serve_refuses_non_loopback_without_token(tmp_path):
    import subprocess

    from test_service_support import FOREST

    r = subprocess.run(
        [str(FOREST), "serve", "--host", "0.0.0.0", "--data", str(tmp_path / "d")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "token" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run(
        [str(FOREST), "serve", "--executor", "kube", "--data", str(tmp_path / "d")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "--executor" in r.stderr
