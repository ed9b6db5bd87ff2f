"""The service's limits come from ``forest serve --max-…`` and reach the API and the page; ``--quiet`` is quiet;
the live preview looks like the final PNG."""

from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from forest.commands.serve import service_limits
from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits

from test_service_support import FOREST, ServeProcess, ServerThread, free_port, tiny_config, wait_for

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def idle_server(data: Path, limits: Limits) -> ServerThread:
    """A service that accepts jobs but runs none."""
    return ServerThread(
        create_app(ServiceConfig(data_dir=data, workers=0, dispatch=False, seed_examples=False, limits=limits))
    )


def png(w: int, h: int) -> bytes:
    """A grey ``w``×``h`` PNG's bytes."""
    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "grey.png"
        buf = oiio.ImageBuf(oiio.ImageSpec(w, h, 3, oiio.UINT8))
        oiio.ImageBufAlgo.fill(buf, (0.5, 0.6, 0.7))
        assert buf.write(str(path))
        return path.read_bytes()


def test_flags_default_to_the_service_defaults():
    assert service_limits() == Limits()
    low = service_limits(max_side=100, max_pixels=5000, max_frames=3, max_upload_mb=0.5, max_spp=4, max_trees=10)
    assert (low.max_width, low.max_height, low.max_pixels, low.max_frames) == (100, 100, 5000, 3)
    assert (low.max_upload_bytes, low.max_spp, low.max_trees) == (2**19, 4, 10)


def test_a_lower_limit_refuses_what_the_default_accepts(tmp_path, monkeypatch):
    from forest import preflight
    from forest.memory import Room

    monkeypatch.setattr(preflight, "memory_room", lambda: Room(6 * 2**30))  # this machine's room, as read now
    job = {"kind": "render", "config": tiny_config(), "settings": {"width": 200, "height": 100}}
    frames = {"kind": "flythrough", "config": tiny_config(), "settings": {"frames": "1-8"}}
    upload = png(64, 64)
    with idle_server(tmp_path / "default", service_limits()) as srv:
        assert httpx.post(srv.url + "/jobs", json=job).status_code == 202
        assert httpx.post(srv.url + "/jobs", json=frames).status_code == 202
        assert httpx.put(srv.url + "/assets/maps/a.png", content=upload).status_code == 201
        assert httpx.get(srv.url + "/health").json()["limits"] == {
            "max_width": 4096,
            "max_height": 4096,
            "max_pixels": 4096 * 2160,
            "max_spp": 1024,
            "max_trees": 2_000_000,
            "max_frames": 2000,
            "max_iterations": 2000,
            "max_upload_bytes": 64 * 2**20,
            "max_config_bytes": 2**20,
            "max_decoded_bytes": 512 * 2**20,
            "max_check_memory_bytes": (768 + 3 * 512) * 2**20,
            "worker_memory_bytes": 6 * 2**30,
        }
    low = service_limits(max_side=128, max_frames=4, max_upload_mb=len(upload) / 2 / 2**20)
    with idle_server(tmp_path / "low", low) as srv:
        r = httpx.post(srv.url + "/jobs", json=job)
        assert r.status_code == 422
        assert r.json()["detail"] == (
            "settings.width/settings.height: 200x100 is over the service limit of 128x128 (settings.width)"
        )
        r = httpx.post(srv.url + "/jobs", json=frames)
        assert (r.status_code, r.json()["detail"]) == (422, "settings.frames: 8 frames is over the service limit of 4")
        r = httpx.put(srv.url + "/assets/maps/a.png", content=upload)
        assert r.status_code == 413 and "limit" in r.json()["detail"]
        limits = httpx.get(srv.url + "/health").json()["limits"]
        assert (limits["max_width"], limits["max_height"], limits["max_frames"]) == (128, 128, 4)
        assert limits["max_upload_bytes"] == low.max_upload_bytes < len(upload)
        assert httpx.get(srv.url + "/jobs").json()["counts"]["total"] == 0  # refused jobs left nothing


def test_health_shows_the_decode_budget_and_the_memory_rooms(tmp_path):
    """/health shows an upload's decode budget, the address space its check runs in, and the room a render is
    checked against at submission: the stated one, or none where submission does not check."""
    from forest.service.assets import check_memory_limit

    limits = Limits(max_decoded_bytes=64 * 2**20, worker_memory_bytes=3 * 2**30)
    with idle_server(tmp_path / "stated", limits) as srv:
        shown = httpx.get(srv.url + "/health").json()["limits"]
    assert shown["max_decoded_bytes"] == 64 * 2**20
    assert shown["max_check_memory_bytes"] == check_memory_limit(64 * 2**20) == (768 + 3 * 64) * 2**20
    assert shown["worker_memory_bytes"] == 3 * 2**30
    with idle_server(tmp_path / "off", Limits(check_memory=False, worker_memory_bytes=3 * 2**30)) as srv:
        assert httpx.get(srv.url + "/health").json()["limits"]["worker_memory_bytes"] is None


def _log_lines(path: Path) -> list[str]:
    return [line for line in path.read_text(errors="replace").splitlines() if line.strip()]


def test_serve_flags_reach_the_api_and_quiet_silences_the_logs(tmp_path):
    quiet = ServeProcess(tmp_path / "q", "--workers", "0", "--max-side", "300", "--max-upload-mb", "2").start()
    try:
        limits = httpx.get(quiet.url + "/health").json()["limits"]
        assert (limits["max_width"], limits["max_height"], limits["max_upload_bytes"]) == (300, 300, 2 * 2**20)
        assert httpx.get(quiet.url + "/jobs/" + "0" * 32).status_code == 404
    finally:
        quiet.stop()
    assert _log_lines(quiet.data.parent / f"serve-{quiet.port}.log") == []  # no banner, no access log

    port = free_port()
    log = tmp_path / "loud.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            [str(FOREST), "serve", "--port", str(port), "--data", str(tmp_path / "l"), "--workers", "0"],
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        try:
            url = f"http://127.0.0.1:{port}"

            def up() -> bool:
                try:
                    return httpx.get(url + "/health", timeout=1).status_code == 200
                except httpx.HTTPError:
                    return proc.poll() is not None

            wait_for(up, timeout=60, step=0.1)
            assert proc.poll() is None
            httpx.get(url + "/jobs/" + "1" * 32)
            wait_for(lambda: "/jobs/" + "1" * 32 in log.read_text(errors="replace"), timeout=10)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(20)
    lines = _log_lines(log)
    assert lines[0].startswith(f"forest service on http://127.0.0.1:{port}/")
    assert any('"GET /jobs/' + "1" * 32 + ' HTTP/1.1" 404' in line for line in lines)  # the access log
    assert not any("Uvicorn running" in line or "Started server process" in line for line in lines)


CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")


@pytest.mark.skipif(not (CHROMIUM.exists() and CHROMEDRIVER.exists()), reason="chromium is not installed")
def test_the_page_takes_its_limits_from_the_api(tmp_path):
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    os.environ["SE_OFFLINE"] = "true"
    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"):
        opts.add_argument(a)
    opts.add_argument(f"--user-data-dir={tmp_path / 'profile'}")
    limits = service_limits(max_side=300, max_spp=16, max_trees=5000)
    with idle_server(tmp_path / "data", limits) as srv:
        driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)), options=opts)
        try:
            driver.get(srv.url + "/")

            def maxes() -> list[str]:
                return driver.execute_script(
                    "return ['#width', '#height', '#spp', '#count'].map(s => document.querySelector(s).max)"
                )

            deadline = time.monotonic() + 30
            while maxes() != ["300", "300", "16", "5000"]:
                assert time.monotonic() < deadline, maxes()
                time.sleep(0.05)
            title = driver.execute_script("return document.querySelector('#asset-files').title")
            assert (
                title == "at most 64 MiB a file on this server; an image at most 512 MiB decoded (checked in 2304 MiB)"
            )
        finally:
            driver.quit()


def test_the_live_preview_goes_through_the_scene_view_and_exposure(tmp_path):
    """The last pass's preview is the final PNG: the same view transform and exposure, not a plain sRGB clip."""
    import OpenImageIO as oiio

    from forest.service.models import Progress, TaskSpec
    from forest.service.runner import TaskContext, execute
    from forest.service.scenecache import SceneCache

    config = tiny_config().replace("subframes = 1", 'subframes = 1\nview = "filmic"\nexposure = 2.5')
    spec = TaskSpec(
        job_id="0" * 32, kind="render", index=0, config=config, output="out/render.exr", frames=(1,), quick_look=False
    )
    job_dir = tmp_path / "job"
    reports: list = []
    ctx = TaskContext(1, 1, job_dir, lambda: job_dir, SceneCache(scenes=1, instance_sets=2), reports.append, ship=True)
    execute(spec, ctx)

    def pixels(data: bytes) -> np.ndarray:
        p = tmp_path / "p.png"
        p.write_bytes(data)
        img = oiio.ImageInput.open(str(p))
        try:
            assert img.spec().get_string_attribute("forest:view") == "filmic"
            return img.read_image(format=oiio.UINT8).astype(int)
        finally:
            img.close()

    previews = [r.files[rel] for r in reports if isinstance(r, Progress) and (rel := "preview/task-0.png") in r.files]
    assert previews, "no pass preview was published"
    last = pixels(previews[-1])
    final = pixels((job_dir / "out" / "render.png").read_bytes())
    assert last.shape == final.shape == (24, 32, 3)
    assert np.abs(last - final).max() <= 1
    assert final.mean() > 20  # a picture, not black
