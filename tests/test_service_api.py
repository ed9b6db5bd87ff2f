"""The job service's HTTP API, driven with httpx against a real server and real renders."""

from __future__ import annotations

import asyncio
import io
import json
import os
import signal
import struct
import subprocess
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits
from forest.service.retention import Retention, sweep

from test_service_support import (
    FOREST,
    ServerThread,
    file_stamps,
    pid_alive,
    read_events,
    stream_events,
    tiny_config,
    wait_for,
    wait_job,
)

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("service-data")
    cfg = ServiceConfig(
        data_dir=data,
        workers=2,
        limits=Limits(
            max_width=512, max_height=512, max_pixels=512 * 384, max_spp=256, max_trees=5000, max_upload_bytes=200_000
        ),
    )
    app = create_app(cfg)
    with ServerThread(app) as srv:
        srv.data = data
        srv.app = app
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


def png_bytes(w: int = 8, h: int = 6, rgb: tuple[int, int, int] = (200, 200, 200)) -> bytes:
    import tempfile

    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "m.png"
        out = oiio.ImageOutput.create(str(p))
        out.open(str(p), oiio.ImageSpec(w, h, 3, oiio.UINT8))
        out.write_image(np.broadcast_to(np.asarray(rgb, np.uint8), (h, w, 3)).copy())
        out.close()
        return p.read_bytes()


def read_png(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def submit(c: httpx.Client, **body) -> str:
    body.setdefault("config", tiny_config())
    r = c.post("/jobs", json=body)
    assert r.status_code == 202, r.text
    return r.json()["id"]


# -- a still: passes published live, ETA, times, names ---------------------------------


def test_still_refines_pass_by_pass_with_eta_and_times(server):
    c = server.client
    jid = submit(c, kind="render", settings={"width": 48, "height": 36, "spp": 64})
    events = read_events(c, jid)
    states = [d["state"] for k, d in events if k == "state"]
    assert states[0] == "queued" and states[-1] == "succeeded" and "running" in states
    passes = [d for k, d in events if k == "progress" and "passes_done" in d]
    # 64 samples in scalar_rgb: eight passes of eight, each reported with the image so far
    assert [d["passes_done"] for d in passes] == list(range(1, 9)) and {d["passes_total"] for d in passes} == {8}
    shown = [d for d in passes if "preview" in d]
    assert shown[0]["passes_done"] == 1 and shown[-1]["passes_done"] == 8 and len(shown) >= 2
    progress = [d["progress"] for k, d in events if k == "progress"]
    assert progress == sorted(progress) and progress[-1] == pytest.approx(1.0)
    etas = [d["eta_s"] for d in passes if d.get("eta_s") is not None]
    assert etas and etas[-1] == 0.0 and all(e >= 0 for e in etas)
    frames = [d for k, d in events if k == "frame"]
    assert [f["frame"] for f in frames] == [1] and frames[0]["thumb"] == "thumbs/frame_0001.png"

    job = c.get(f"/jobs/{jid}").json()
    assert job["state"] == "succeeded" and job["progress"] == 1.0 and job["eta_s"] == 0.0
    assert job["name"] == "tiny"  # the config's name
    assert job["created"] <= job["started"] <= job["finished"] and job["elapsed_s"] > 0
    task = job["tasks"][0]
    assert task["attempt"] == 1 and task["seconds"] > 0 and task["frames_done"] == [1]
    res = c.get(f"/jobs/{jid}/result").json()
    paths = {o["path"] for o in res["outputs"]}
    assert {"out/render.exr", "out/render.png", "thumbs/frame_0001.png"} <= paths
    # trees: the trees rendered, not the candidate count of the config
    assert job["trees"] == res["stats"][0]["trees"] and 0 < job["trees"] <= job["settings"]["candidates"] == 300
    assert read_png(c.get(res["image"]).content) == (48, 36)
    assert read_png(c.get(job["preview"]).content) == (48, 36)
    log = c.get(f"/jobs/{jid}/log").text
    assert "started on pid:" in log and "succeeded" in log
    assert "still rendered" in c.get(task["log"]).text
    assert (server.data / "jobs" / jid / "config.toml").read_text() == tiny_config()


def test_a_large_still_shows_a_quick_look_before_its_first_pass(server):
    c = server.client
    jid = submit(c, kind="render", settings={"width": 400, "height": 300, "spp": 8})
    events = read_events(c, jid)
    shown = [(d["message"], d.get("passes_done")) for k, d in events if k == "progress" and "preview" in d]
    assert shown[0] == ("quick look", None) and shown[1][1] == 1, shown
    quick = next(d for k, d in events if k == "progress" and d["message"] == "quick look")
    assert quick["preview"] == "preview/task-0.png"
    assert read_png(c.get(c.get(f"/jobs/{jid}").json()["preview"]).content) == (400, 300)


# -- frames as tasks -------------------------------------------------------------------


def test_six_frame_flythrough_is_six_tasks_on_workers_that_keep_the_scene(server):
    c = server.client
    r = c.post("/jobs", json={"kind": "flythrough", "config": tiny_config(), "settings": {"frames": "1-6"}})
    assert r.status_code == 202, r.text
    assert [t["frames"] for t in r.json()["tasks"]] == [[f] for f in range(1, 7)]
    jid = r.json()["id"]
    job = wait_job(c, jid)
    assert job["state"] == "succeeded", job
    assert job["frames_total"] == job["frames_done"] == 6
    for t in job["tasks"]:
        assert t["state"] == "succeeded" and t["attempt"] == 1 and t["seconds"] > 0
        assert t["frames_done"] == t["frames"] and t["worker"].startswith("pid:")
        assert f"frame {t['frames'][0]} rendered" in c.get(t["log"]).text
        assert "variant: scalar_rgb ([render] variant)" in c.get(t["log"]).text  # the choice and why
    # two worker processes at most: each loads the scene once and keeps it for the frames after
    log = c.get(f"/jobs/{jid}/log").text
    workers = {t["worker"] for t in job["tasks"]}
    assert log.count(" loaded in ") <= len(workers) <= 2 and log.count(" cached: ") >= 6 - len(workers)
    frames = c.get(f"/jobs/{jid}/frames").json()
    assert [f["frame"] for f in frames] == list(range(1, 7)) and {f["state"] for f in frames} == {"done"}
    thumb = c.get(frames[0]["thumb"])
    assert thumb.status_code == 200 and read_png(thumb.content) == (32, 24)
    assert read_png(c.get(frames[5]["png"]).content) == (32, 24)
    res = c.get(f"/jobs/{jid}/result").json()
    assert sorted(o["path"] for o in res["outputs"] if o["path"].startswith("out/")) == sorted(
        f"out/frame_{f:04d}.{e}" for f in range(1, 7) for e in ("exr", "png")
    )
    assert [s["frames"] for s in res["stats"]] == [[f] for f in range(1, 7)]


def test_worker_killed_during_frame_3_keeps_frames_1_and_2(server):
    c = server.client
    jid = submit(
        c,
        kind="flythrough",
        name="kill test",
        settings={"frames": "1-6", "frames_per_task": 6, "width": 96, "height": 72, "spp": 128},
    )
    out = server.data / "jobs" / jid / "out"
    for kind, d in stream_events(c, jid):
        if kind == "progress" and d.get("frame") == 3 and d.get("passes_done", 0) < d.get("passes_total", 0):
            break
    before = file_stamps(out, "frame_*")
    task = c.get(f"/jobs/{jid}").json()["tasks"][0]
    pid = int(task["worker"].split(":")[1])
    busy = [w for w in c.get("/workers").json()["workers"] if w["state"] == "busy" and w["job_id"] == jid]
    os.kill(pid, signal.SIGKILL)
    assert set(before) == {"frame_0001.exr", "frame_0001.png", "frame_0002.exr", "frame_0002.png"}
    assert busy and busy[0]["pid"] == pid and busy[0]["job_name"] == "kill test" and busy[0]["task"] == 0

    job = wait_job(c, jid)
    assert job["state"] == "succeeded", job
    assert job["tasks"][0]["attempt"] == 2 and not pid_alive(pid)
    after = file_stamps(out, "frame_*")
    assert len(after) == 12
    assert {k: after[k] for k in before} == before  # frames 1 and 2 were not written again
    frames = {f["frame"]: f for f in c.get(f"/jobs/{jid}/frames").json()}
    assert [frames[f]["attempt"] for f in range(1, 7)] == [1, 1, 2, 2, 2, 2]
    log = c.get(f"/jobs/{jid}/log").text
    assert "worker lost" in log and "frames on disk, not rendered again: 1-2" in log


def test_requeue_one_frame_renders_it_alone_again(server):
    c = server.client
    jid = submit(c, kind="flythrough", settings={"frames": "1-3"})
    assert wait_job(c, jid)["state"] == "succeeded"
    out = server.data / "jobs" / jid / "out"
    before = file_stamps(out)
    r = c.post(f"/jobs/{jid}/frames/2/requeue")
    assert r.status_code == 202 and r.json()["state"] in ("queued", "running")
    assert r.json()["finished"] is None and r.json()["frames_done"] == 2
    job = wait_job(c, jid)
    assert job["state"] == "succeeded" and job["frames_done"] == 3
    after = file_stamps(out)
    changed = {k for k in before if after[k] != before[k]}
    assert changed == {"frame_0002.exr", "frame_0002.png"}
    assert [t["attempt"] for t in job["tasks"]] == [1, 1, 1]
    assert c.post(f"/jobs/{jid}/frames/9/requeue").status_code == 404
    assert c.post(f"/jobs/{jid}/tasks/7/requeue").status_code == 404
    # a whole task, by index
    r = c.post(f"/jobs/{jid}/tasks/0/requeue")
    assert r.status_code == 202
    assert wait_job(c, jid)["state"] == "succeeded"
    again = file_stamps(out)
    assert again["frame_0001.exr"] != before["frame_0001.exr"] and again["frame_0003.exr"] == before["frame_0003.exr"]


def test_requeue_of_a_task_that_still_runs_is_refused(idle):
    c = idle.client
    jid = submit(c, kind="flythrough", settings={"frames": "1-2"})
    r = c.post(f"/jobs/{jid}/tasks/0/requeue")
    assert r.status_code == 409 and "queued" in r.json()["detail"]


# -- downloads ---------------------------------------------------------------------------


def test_downloads_return_the_right_bytes(server, tmp_path):
    c = server.client
    jid = submit(c, kind="flythrough", settings={"frames": "1-2"})
    assert wait_job(c, jid)["state"] == "succeeded"
    root = server.data / "jobs" / jid
    for rel in ("out/frame_0001.exr", "out/frame_0002.png", "thumbs/frame_0002.png"):
        r = c.get(f"/jobs/{jid}/files/{rel}")
        assert r.status_code == 200 and r.content == (root / rel).read_bytes()
    res = c.get(f"/jobs/{jid}/result").json()
    labels = {d["label"]: d["url"] for d in res["downloads"]}
    z = c.get(labels["EXR frames (zip)"])
    assert z.status_code == 200 and z.headers["content-type"] == "application/zip"
    assert 'filename="tiny-exr.zip"' in z.headers["content-disposition"]
    with zipfile.ZipFile(io.BytesIO(z.content)) as zf:
        assert zf.namelist() == ["frame_0001.exr", "frame_0002.exr"]
        for name in zf.namelist():
            assert zf.read(name) == (root / "out" / name).read_bytes()
    # the same archive again: the same bytes
    assert c.get(labels["EXR frames (zip)"]).content == z.content
    assert c.get(f"/jobs/{jid}/outputs.zip", params={"ext": "tif"}).status_code == 404
    assert c.get(f"/jobs/{jid}/outputs.zip", params={"folder": "out/../.."}).status_code == 422
    assert c.get(f"/jobs/{jid}/files/config.toml").status_code == 404
    assert c.get(f"/jobs/{jid}/files/out/../config.toml").status_code == 404

    # what the service rendered is what `forest render` renders for the same frame
    scene = tmp_path / "tiny.toml"
    scene.write_text(tiny_config())
    cli = subprocess.run(
        [str(FOREST), "render", str(scene), "--frames", "2", "-o", str(tmp_path / "cli" / "frame_####.exr")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert cli.returncode == 0, cli.stderr
    assert (tmp_path / "cli" / "frame_0002.exr").read_bytes() == (root / "out" / "frame_0002.exr").read_bytes()


def test_export_jobs_download_as_the_cli_writes_them(server, tmp_path):
    c = server.client
    if not c.get("/health").json()["capabilities"]["rib"]:
        pytest.skip("the RIB export is not installed")
    jid = submit(c, kind="rib", settings={"frames": "1-2"})
    job = wait_job(c, jid)
    assert job["state"] == "succeeded", job
    res = c.get(f"/jobs/{jid}/result").json()
    url = {d["label"]: d["url"] for d in res["downloads"]}["RIB export (zip)"]
    with zipfile.ZipFile(io.BytesIO(c.get(url).content)) as zf:
        got = {n: zf.read(n) for n in zf.namelist()}
    scene = tmp_path / "tiny.toml"
    scene.write_text(tiny_config())
    cli = subprocess.run(
        [str(FOREST), "export", "rib", str(scene), "--frames", "1-2", "-o", str(tmp_path / "rib")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert cli.returncode == 0, cli.stderr
    want = {
        p.relative_to(tmp_path / "rib").as_posix(): p.read_bytes() for p in (tmp_path / "rib").rglob("*") if p.is_file()
    }
    assert sorted(got) == sorted(want) and any(n.endswith(".rib") for n in got)
    assert got == want


def test_usd_export_downloads_as_the_cli_writes_it(server, tmp_path):
    c = server.client
    if not c.get("/health").json()["capabilities"]["usd"]:
        pytest.skip("usd-core is not installed")
    jid = submit(c, kind="usd", settings={"frames": "1-2"})
    job = wait_job(c, jid)
    assert job["state"] == "succeeded", job
    res = c.get(f"/jobs/{jid}/result").json()
    url = {d["label"]: d["url"] for d in res["downloads"]}["USD stage and species layers (zip)"]
    with zipfile.ZipFile(io.BytesIO(c.get(url).content)) as zf:
        got = {n: zf.read(n) for n in zf.namelist()}
    scene = tmp_path / "tiny.toml"
    scene.write_text(tiny_config())
    out = tmp_path / "usd"
    cli = subprocess.run(
        [str(FOREST), "export", "usd", str(scene), "--frames", "1-2", "-o", str(out / "tiny.usdc")],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert cli.returncode == 0, cli.stderr
    want = {p.relative_to(out).as_posix(): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert "tiny.usdc" in got and sorted(got) == sorted(want)
    assert got == want


# -- retention ----------------------------------------------------------------------------


def test_retention_forgets_finished_jobs_but_keeps_their_outputs(server):
    c = server.client
    jid = submit(c, kind="render")
    assert wait_job(c, jid)["state"] == "succeeded"
    png = c.get(f"/jobs/{jid}/files/out/render.png").content
    svc = server.app.state.service
    done = sweep(svc.store, svc.datadir, Retention(max_jobs=0, events_max_age_s=0.0))
    assert jid in done["pruned"]
    assert jid not in {j["id"] for j in c.get("/jobs", params={"limit": 500}).json()["jobs"]}
    assert svc.store.events_after(jid, 0) == []
    # its folder stays: the job is still shown (archived) and its files still download
    job = c.get(f"/jobs/{jid}").json()
    assert job["archived"] and job["state"] == "succeeded" and job["name"] == "tiny"
    assert c.get(f"/jobs/{jid}/files/out/render.png").content == png
    assert c.get(f"/jobs/{jid}/frames").json()[0]["state"] == "done"
    # until the user deletes it
    assert c.delete(f"/jobs/{jid}").status_code == 204
    assert c.get(f"/jobs/{jid}").status_code == 404 and not (server.data / "jobs" / jid).exists()


# -- cancel and resume ----------------------------------------------------------------------


def test_cancel_stops_the_worker_and_resume_finishes_the_job(server):
    c = server.client
    jid = submit(c, kind="flythrough", priority=50, settings={"frames": "1-8", "frames_per_task": 8, "spp": 64})
    task = wait_for(
        lambda: next(
            (t for t in c.get(f"/jobs/{jid}").json()["tasks"] if t["state"] == "running" and t["worker"]), None
        )
    )
    pid = int(task["worker"].split(":")[1])
    assert c.post(f"/jobs/{jid}/cancel").status_code == 202
    job = wait_job(c, jid)
    assert job["state"] == "canceled" and job["tasks"][0]["state"] == "canceled"
    wait_for(lambda: not pid_alive(pid), timeout=10)
    assert c.post(f"/jobs/{jid}/cancel").status_code == 409
    assert c.get(f"/jobs/{jid}/result").status_code == 409
    kept = file_stamps(server.data / "jobs" / jid / "out", "frame_*.exr")
    assert c.post(f"/jobs/{jid}/resume").status_code == 202
    job = wait_job(c, jid)
    assert job["state"] == "succeeded" and job["frames_done"] == 8
    after = file_stamps(server.data / "jobs" / jid / "out", "frame_*.exr")
    assert {k: after[k] for k in kept} == kept  # what was on disk stayed


def test_cancel_of_a_queued_job_is_immediate_and_counted(idle):
    c = idle.client
    jid = submit(c, kind="flythrough", settings={"frames": "1-4"})
    r = c.post(f"/jobs/{jid}/cancel")
    assert r.status_code == 202 and r.json()["state"] == "canceled"
    assert {t["state"] for t in r.json()["tasks"]} == {"canceled"}
    assert c.post(f"/jobs/{jid}/cancel").status_code == 409
    counts = c.get("/jobs").json()["counts"]
    assert counts["canceled"] == 1 and counts["total"] == sum(counts[s] for s in counts if s != "total") == 1
    r = c.post(f"/jobs/{jid}/retry")  # the old name of resume
    assert r.status_code == 202 and r.json()["state"] == "queued"
    assert c.post(f"/jobs/{jid}/resume").status_code == 409


# -- errors ----------------------------------------------------------------------------------


def test_a_misspelled_species_is_refused_at_submission(server):
    c = server.client
    before = c.get("/jobs").json()["counts"]
    text = tiny_config().replace('model = "shrub"', 'model = "no_such_species"')
    r = c.post("/jobs", json={"kind": "render", "config": text})
    assert r.status_code == 422 and r.json()["detail"].startswith("config: species[0].model: unknown species"), r.text
    assert c.get("/jobs").json()["counts"] == before


def test_a_render_error_fails_the_job_once_with_its_message(server, tmp_path):
    import OpenImageIO as oiio

    c = server.client
    # an EXR of two channels decodes, but Mitsuba's envmap refuses it: only the worker can tell
    path = tmp_path / "two.exr"
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(8, 4, 2, oiio.FLOAT))
    out.write_image(np.ones((4, 8, 2), np.float32))
    out.close()
    assert c.put("/assets/skies/two.exr", content=path.read_bytes()).status_code == 201
    text = tiny_config() + '[lights]\nsky = { envmap = "skies/two.exr" }\n'
    r = c.post("/jobs", json={"kind": "render", "config": text})
    assert r.status_code == 202, r.text
    job = wait_job(c, r.json()["id"])
    assert job["state"] == "failed" and "lights.sky.envmap: skies/two.exr" in job["error"], job
    assert job["tasks"][0]["attempt"] == 1 and "skies/two.exr" in job["tasks"][0]["error"]
    assert str(server.data) not in job["error"]
    res = c.get(f"/jobs/{job['id']}/result")
    assert res.status_code == 409 and "skies/two.exr" in res.json()["detail"]
    assert "skies/two.exr" in c.get(f"/jobs/{job['id']}/log").text


def test_library_errors_name_the_request_field_not_a_cli_flag(server):
    c = server.client
    r = c.post("/jobs", json={"kind": "flythrough", "config": tiny_config(), "settings": {"frames": "9-2"}})
    assert r.status_code == 422 and r.json()["detail"] == "settings.frames: bad range '9-2'"
    from forest.runtime import cuda_available

    if cuda_available():
        return
    # raised inside the worker by the renderer; the task's error names the JSON field
    jid = submit(c, kind="render", settings={"variant": "cuda_ad_rgb"})
    job = wait_job(c, jid)
    assert job["state"] == "failed"
    assert job["tasks"][0]["error"].startswith("settings.variant: cuda_ad_rgb needs an NVIDIA GPU"), job
    assert "--" not in job["error"]


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
        ({"spp": 257}, "settings.spp"),
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


# -- assets ------------------------------------------------------------------------------------


def test_an_upload_is_refused_by_its_decoded_size_before_it_is_decoded(tmp_path):
    """A small file can hold a huge image (a 1 MB PNG of 16384×16000 RGBA decodes to 4 GiB, which killed the
    service): the decoded size, from the header, is limited (max_decoded_bytes), and nothing is stored."""
    limits = Limits(max_decoded_bytes=1 << 20)  # 1 MiB: a 512×512 RGB image (3 MiB as float32) is over it
    with ServerThread(
        create_app(ServiceConfig(data_dir=tmp_path / "data", workers=0, dispatch=False, limits=limits))
    ) as srv:
        with httpx.Client(base_url=srv.url, timeout=30) as c:
            big = png_bytes(512, 512)
            assert len(big) < 20_000  # small on disk
            r = c.put("/assets/big.png", content=big)
            assert r.status_code == 422 and "512x512" in r.json()["detail"] and "MiB limit" in r.json()["detail"]
            assert c.put("/assets/small.png", content=png_bytes(64, 64)).status_code == 201
    assets = tmp_path / "data" / "assets"
    assert not (assets / "big.png").exists() and not list(assets.rglob(".upload.*"))


def test_half_stored_uploads_are_removed_at_start_up(tmp_path):
    """An upload a killed service was storing (its temporary file) does not survive a restart."""
    assets = tmp_path / "data" / "assets" / "maps"
    assets.mkdir(parents=True)
    (assets / ".upload.abc123.png").write_bytes(b"half a png")
    (assets / "kept.png").write_bytes(png_bytes())
    cfg = ServiceConfig(data_dir=tmp_path / "data", workers=0, dispatch=False, seed_examples=False)
    with ServerThread(create_app(cfg)):
        pass
    assert sorted(p.name for p in assets.iterdir()) == ["kept.png"]


def test_uploads_are_checked_and_size_limited(server):
    c = server.client
    ok = c.put("/assets/presence.png", content=png_bytes())
    assert ok.status_code == 201 and ok.json()["width"] == 8 and ok.json()["kind"] == "image"
    assert c.put("/assets/fake.png", content=b"this is not an image").status_code == 415
    assert c.put("/assets/huge.png", content=b"\0" * 200_001).status_code == 413
    assert c.put("/assets/notes.txt", content=b"hello").status_code == 415
    assert c.put("/assets/..png", content=png_bytes()).status_code == 422
    assert c.put("/assets/" + "/".join("abcdefghij") + ".png", content=png_bytes()).status_code == 422
    assert c.put("/assets/maps/.hidden.png", content=png_bytes()).status_code == 422
    assert c.put("/assets/maps/%2E%2E/up.png", content=png_bytes()).status_code in (404, 422)
    import trimesh

    ply = trimesh.creation.box().export(file_type="ply")
    mesh = c.put("/assets/meshes/box.ply", content=ply)
    assert mesh.status_code == 201 and mesh.json()["triangles"] == 12 and mesh.json()["name"] == "meshes/box.ply"
    assert c.put("/assets/empty.ply", content=b"ply\nformat ascii 1.0\nend_header\n").status_code == 415
    assert c.put("/assets/presence.png/x.png", content=png_bytes()).status_code == 409
    names = {a["name"] for a in c.get("/assets").json()}
    assert {"presence.png", "meshes/box.ply"} <= names and "fake.png" not in names
    assert not [p for p in (server.data / "assets").rglob(".upload*")]


def test_uploads_keep_their_folders_so_configs_submit_unchanged(server):
    c = server.client
    assert c.put("/assets/scene7/maps/mask.png", content=png_bytes(16, 16)).status_code == 201
    text = tiny_config().replace("[scatter]", '[maps]\npresence = "scene7/maps/mask.png"\n[scatter]')
    r = c.post("/jobs", json={"kind": "render", "config": text})
    assert r.status_code == 202, r.text
    jid = r.json()["id"]
    linked = server.data / "jobs" / jid / "scene7" / "maps" / "mask.png"
    assert linked.read_bytes() == (server.data / "assets" / "scene7" / "maps" / "mask.png").read_bytes()
    assert wait_job(c, jid)["state"] == "succeeded"


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


# -- look-dev ----------------------------------------------------------------------------------


def test_match_job_fits_the_look_and_offers_the_fitted_scene(server):
    c = server.client
    if not c.get("/health").json()["capabilities"]["match"]:
        pytest.skip("look-dev is not installed")
    assert c.put("/assets/ref.png", content=png_bytes(32, 24)).status_code == 201
    bad = c.post(
        "/jobs", json={"kind": "match", "config": tiny_config(), "settings": {"reference": "ref.png", "mode": "bogus"}}
    )
    assert bad.status_code == 422 and bad.json()["detail"].startswith("settings.mode: must be one of")
    # the regions painted over the reference travel with the job (forest match --mask)
    assert c.put("/assets/masks/canopy.png", content=png_bytes(32, 24, (0, 255, 0))).status_code == 201
    assert c.put("/assets/masks/tall.png", content=png_bytes(12, 30, (0, 255, 0))).status_code == 201
    tall = c.post(
        "/jobs",
        json={"kind": "match", "config": tiny_config(), "settings": {"reference": "ref.png", "mask": "masks/tall.png"}},
    )
    assert tall.status_code == 422 and tall.json()["detail"].startswith("settings.mask: masks/tall.png: mask is 12x30")
    render_mask = c.post("/jobs", json={"kind": "render", "config": tiny_config(), "settings": {"mask": "ref.png"}})
    assert (
        render_mask.status_code == 422 and render_mask.json()["detail"] == "settings.mask: applies to match jobs only"
    )
    fit = {"reference": "ref.png", "mask": "masks/canopy.png", "iterations": 2, "resolution": 16, "match_spp": 1}
    jid = submit(c, kind="match", settings=fit)
    job = wait_job(c, jid, timeout=180)
    assert job["state"] == "succeeded", job
    res = c.get(f"/jobs/{jid}/result").json()
    paths = {o["path"] for o in res["outputs"]}
    assert "out/match.json" in paths and "out/scene.toml" in paths
    labels = {d["label"]: d["url"] for d in res["downloads"]}
    scene = c.get(labels["fitted scene (scene.toml)"])
    assert (
        scene.status_code == 200 and scene.content == (server.data / "jobs" / jid / "out" / "scene.toml").read_bytes()
    )
    assert read_png(c.get(labels["look-dev report (report.png)"]).content)[0] > 0
    # painted all canopy: the fit's statistics know no sky or ground (automatic regions find both here)
    figures = json.loads((server.data / "jobs" / jid / "out" / "match.json").read_text())["figures"]
    assert set(figures["start_regions"]) == set(figures["fitted_regions"]) == {"canopy", "whole image"}
    assert res["stats"][0]["losses"] and c.get(job["preview"]).status_code == 200


# -- names, filters, counts, idempotency, concurrency, auth (no renders) -------------------------


def test_names_filters_and_counts_that_add_up(idle):
    c = idle.client
    a = submit(c, kind="render")  # named by its config
    b = submit(c, kind="render", name="Valley take 2")
    d = submit(c, kind="flythrough", name="valley fly", settings={"frames": "1-2"})
    c.post(f"/jobs/{d}/cancel")
    jobs = {j["id"]: j for j in c.get("/jobs").json()["jobs"]}
    assert jobs[a]["name"] == "tiny" and jobs[b]["name"] == "Valley take 2"
    assert [j["id"] for j in c.get("/jobs", params={"name": "VALLEY"}).json()["jobs"]] == [d, b]
    assert [j["id"] for j in c.get("/jobs", params={"name": "valley", "state": "canceled"}).json()["jobs"]] == [d]
    assert c.get("/jobs", params={"name": "100%_"}).json()["jobs"] == []
    counts = c.get("/jobs").json()["counts"]
    assert counts == {"queued": 2, "running": 0, "succeeded": 0, "failed": 0, "canceled": 1, "total": 3}
    assert c.get("/health").json()["counts"] == counts


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


def test_event_streams_sleep_on_notifications_and_close(idle):
    c = idle.client
    jid = submit(c, kind="render")
    seen = []

    def watch():
        for kind, data in stream_events(c, jid, timeout=30):
            seen.append((kind, data))
            if kind == "cancel":
                return

    import threading

    t = threading.Thread(target=watch)
    t.start()
    wait_for(lambda: c.get("/health").json()["streams"] == 1, timeout=10)
    c.post(f"/jobs/{jid}/cancel")  # a write to the store wakes the stream at once
    t.join(10)
    assert not t.is_alive() and ("cancel", {"message": "cancel requested"}) in seen
    wait_for(lambda: c.get("/health").json()["streams"] == 0, timeout=10)


def test_token_is_required_when_configured(tmp_path):
    app = create_app(ServiceConfig(data_dir=tmp_path / "d", workers=0, dispatch=False, token="s3cret-token"))
    with ServerThread(app) as srv, httpx.Client(base_url=srv.url) as c:
        assert c.get("/jobs").status_code == 401
        assert c.get("/workers").status_code == 401
        assert c.get("/jobs", headers={"Authorization": "Bearer wrong-token"}).status_code == 401
        assert c.get("/jobs", headers={"Authorization": "Bearer s3cret-token"}).status_code == 200
        assert c.get("/jobs", params={"access_token": "s3cret-token"}).status_code == 200
        assert (
            c.post("/jobs", params={"access_token": "s3cret-token"}, json={"kind": "render", "config": "x"}).status_code
            == 401
        )
        assert c.get("/").status_code == 200  # the page itself asks for the token


def test_one_service_per_data_folder(server):
    r = subprocess.run(
        [str(FOREST), "serve", "--data", str(server.data), "--port", "0"], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and "another forest service" in r.stderr


def test_serve_refuses_non_loopback_without_token(tmp_path):
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
