"""``forest submit`` and :mod:`forest.client` against a live service: a tiny render submitted with its map, followed
to the end and downloaded; a failing job, a refused one and an unreachable server as one line each; ``HEAD`` on the
downloads."""

from __future__ import annotations

import io
import subprocess
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest

from forest.client import ServiceClient, ServiceError, scene_files
from forest.service.app import ServiceConfig, create_app

from test_service_support import FOREST, ServerThread, free_port, tiny_config

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("submit-data")
    with ServerThread(create_app(ServiceConfig(data_dir=data, workers=1, seed_examples=False))) as srv:
        yield srv


def write_png(path: Path, rgb: tuple[int, int, int]) -> None:
    import OpenImageIO as oiio

    path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(8, 8, 3, oiio.UINT8))
    out.write_image(np.full((8, 8, 3), rgb, np.uint8))
    out.close()


@pytest.fixture()
def scene(tmp_path) -> Path:
    """The tiny scene with a colour map beside it, as an artist keeps it on disk."""
    folder = tmp_path / "shot"
    write_png(folder / "maps" / "colour.png", (90, 140, 60))
    path = folder / "scene.toml"
    path.write_text(tiny_config(count=120) + '\n[maps]\ncolour = "./maps/colour.png"\n')
    return path


def forest(*args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    return subprocess.run([str(FOREST), *args], capture_output=True, text=True, timeout=timeout)


def test_submit_waits_with_progress_and_downloads_the_outputs(server, scene, tmp_path):
    out = tmp_path / "renders"
    r = forest("submit", str(scene), "--server", server.url, "--wait", "-o", str(out), "--interval", "0.2")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    job_id = lines[0]
    assert len(job_id) == 32 and int(job_id, 16) >= 0
    progress = [line for line in lines if line.startswith("Progress: ")]
    assert progress[-1].startswith("Progress: 100% succeeded")
    assert all(line.split()[1].endswith("%") for line in progress)
    assert f"job {job_id} succeeded" in r.stdout
    assert "uploading maps/colour.png" in r.stderr
    assert sorted(p.name for p in out.iterdir()) == ["render.exr", "render.png"]
    assert f"wrote {out / 'render.exr'}" in r.stdout
    # the service rendered the scene with the uploaded map: the same bytes as its own output
    with httpx.Client(base_url=server.url) as c:
        assert (out / "render.png").read_bytes() == c.get(f"/jobs/{job_id}/files/out/render.png").content
        assert c.get("/assets").json()[0]["name"] == "maps/colour.png"


def test_head_on_downloads_answers_the_get_headers_without_a_body(server, scene):
    with ServiceClient(server.url) as client:
        job = client.submit_scene(scene)
        client.wait(job["id"], interval=0.1)
    with httpx.Client(base_url=server.url) as c:
        for url in (
            f"/jobs/{job['id']}/outputs.zip",
            f"/jobs/{job['id']}/outputs.zip?ext=exr",
            f"/jobs/{job['id']}/files/out/render.png",
            f"/jobs/{job['id']}/log",
            f"/jobs/{job['id']}/result",
        ):
            get, head = c.get(url), c.head(url)
            assert (head.status_code, get.status_code) == (200, 200), url
            assert head.content == b""
            for h in ("content-type", "content-length", "content-disposition"):
                assert head.headers.get(h) == get.headers.get(h), (url, h)
            assert int(head.headers["content-length"]) == len(get.content)
        assert c.head(f"/jobs/{'0' * 32}/outputs.zip").status_code == 404


def test_client_download_keeps_folders_and_writes_whole_files(server, scene, tmp_path):
    with ServiceClient(server.url) as client:
        job = client.submit_scene(scene, "rib")
        done = client.wait(job["id"], interval=0.1)
        assert done["state"] == "succeeded"
        files = client.download(job["id"], tmp_path / "rib", folder="out/rib")
        assert files and all(p.is_file() and p.stat().st_size > 0 for p in files)
        z = httpx.get(f"{server.url}/jobs/{job['id']}/outputs.zip", params={"folder": "out/rib"})
        names = zipfile.ZipFile(io.BytesIO(z.content)).namelist()
        assert sorted(p.relative_to(tmp_path / "rib").as_posix() for p in files) == sorted(names)


def test_a_failed_job_exits_1_with_its_error(server, scene):
    # an EXR environment map of two channels decodes, but Mitsuba refuses it: the job fails when it runs
    import OpenImageIO as oiio

    sky = scene.parent / "sky.exr"
    out = oiio.ImageOutput.create(str(sky))
    out.open(str(sky), oiio.ImageSpec(8, 4, 2, oiio.FLOAT))
    out.write_image(np.ones((4, 8, 2), np.float32))
    out.close()
    scene.write_text(scene.read_text() + '\n[lights.sky]\nenvmap = "sky.exr"\n')
    r = forest("submit", str(scene), "--server", server.url, "--wait", "--interval", "0.2")
    assert r.returncode == 1, r.stdout + r.stderr
    err = r.stderr.strip().splitlines()[-1]
    assert err.startswith(
        f"forest: error: job {r.stdout.split()[0]} failed: task 0: lights.sky.envmap: sky.exr: Mitsuba"
    )
    assert "Traceback" not in r.stderr and r.stdout.splitlines()[-1].startswith("Progress: ")


def test_mistakes_are_one_line_and_exit_2(server, scene, tmp_path):
    r = forest("submit", str(scene), "--server", server.url, "--spp", "0")
    assert (r.returncode, r.stdout) == (2, "")
    assert r.stderr.startswith("forest: error: ") and "--spp" in r.stderr and r.stderr.count("\n") == 1
    r = forest("submit", str(scene), "--server", server.url, "--width", "100000")
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.splitlines() == [
        "uploading maps/colour.png",
        "forest: error: submitting the job: refused (422): settings.width: must be <= 16384, got 100000",
    ]
    r = forest("submit", str(scene), "--server", f"http://127.0.0.1:{free_port()}")
    assert r.returncode == 2 and "cannot reach the forest service" in r.stderr and r.stderr.count("\n") == 1
    missing = tmp_path / "other" / "scene.toml"
    missing.parent.mkdir()
    missing.write_text(tiny_config() + '\n[maps]\ncolour = "maps/none.png"\n')
    r = forest("submit", str(missing), "--server", server.url)
    assert r.returncode == 2
    assert r.stderr.strip() == f"forest: error: {missing}: maps.colour: maps/none.png: file not found"


def test_scene_files_refuse_paths_outside_the_scene_folder(tmp_path):
    write_png(tmp_path / "colour.png", (1, 2, 3))
    scene = tmp_path / "shot" / "scene.toml"
    scene.parent.mkdir()
    scene.write_text(tiny_config() + '\n[maps]\ncolour = "../colour.png"\n')
    with pytest.raises(Exception, match=r"maps.colour: '../colour.png' is outside the config's folder"):
        scene_files(scene)


def test_client_names_a_refused_request_and_an_unknown_job(server):
    with ServiceClient(server.url) as client:
        with pytest.raises(ServiceError, match=r"reading job 0+: refused \(404\): job 0+ not found") as e:
            client.job("0" * 32)
        assert e.value.status == 404 and e.value.exit_code == 2
        limits = client.health()["limits"]
        assert limits["max_width"] == 4096


class InterruptedClient:
    """A ServiceClient whose wait is interrupted (Ctrl-C) after the job was submitted."""

    def __init__(self, server: str, token: str | None = None):
        self.server = server

    def __enter__(self) -> InterruptedClient:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def health(self) -> dict:
        return {}

    def submit_scene(self, scene, kind, **_kw) -> dict:
        return {"id": "ab" * 16}

    def wait(self, job_id: str, **_kw) -> dict:
        raise KeyboardInterrupt


def test_ctrl_c_while_waiting_says_the_job_goes_on_and_how_to_cancel_it(scene, monkeypatch, capsys):
    import forest.client
    from forest.cli import main

    monkeypatch.setattr(forest.client, "ServiceClient", InterruptedClient)
    with pytest.raises(SystemExit) as e:
        main(["submit", str(scene), "--server", "http://farm:8000", "--wait"])
    out, err = capsys.readouterr()
    assert e.value.code == 130 and out.splitlines() == ["ab" * 16]
    assert err.strip() == (
        f"interrupted: job {'ab' * 16} keeps running on the server; "
        f"cancel it with: forest submit --cancel {'ab' * 16} --server http://farm:8000"
    )


def test_submit_cancel_stops_a_job_on_the_service(server, scene, tmp_path):
    with ServiceClient(server.url) as client:  # eight frames at 512 spp: still running when canceled
        job = client.submit_scene(scene, "flythrough", settings={"frames": "1-8", "spp": 512})
        r = forest("submit", "--cancel", job["id"], "--server", server.url)
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith(f"job {job['id']}: cancel requested (")
        assert client.wait(job["id"], interval=0.1, check=False)["state"] == "canceled"
    r = forest("submit", str(scene), "--cancel", job["id"], "--server", server.url)
    assert r.returncode == 2 and r.stderr.startswith("forest: error: --cancel: ") and r.stderr.count("\n") == 1
    r = forest("submit", "--server", server.url)
    assert r.returncode == 2 and r.stderr.startswith("forest: error: SCENE: ") and r.stderr.count("\n") == 1
