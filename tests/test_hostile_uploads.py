"""Hostile uploads (issue 28): a small file that declares a huge image cannot kill the job service.

A 1 MB PNG of 16384×16000 RGBA once decoded to float32 inside the service and got it
OOM-killed, leaving its half-stored upload behind.  Now the upload is checked in a child
process: its header is read first and the decoded size (width × height × channels × 4 bytes)
refused over the decode budget before anything is decoded; what still decodes does so under
the child's address-space limit, so a file that exhausts it kills only the child.  Each case
answers 4xx with one line, stores nothing, and leaves the service answering.
"""

from __future__ import annotations

import os
import resource
import struct
import threading
import time
import zlib
from pathlib import Path

import httpx
import pytest

from forest.service import assets
from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits

from test_service_support import ServeProcess, ServerThread

MiB = 2**20


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def huge_png(width: int, height: int, rows: int = 16) -> bytes:
    """An RGBA 8-bit PNG declaring ``width``×``height`` whose data holds only ``rows`` rows of zeros
    (``rows=height``: the whole image, still small: zeros compress ~1000:1)."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    z = zlib.compressobj(9)
    row = b"\0" * (1 + 4 * width)
    data = b"".join(z.compress(row) for _ in range(rows)) + z.flush()
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", data) + _chunk(b"IEND", b"")


def small_png() -> bytes:
    return huge_png(16, 8, rows=8)


def _peak_rss() -> int:
    """This process's peak resident size, bytes (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _stored(data: Path) -> list[str]:
    """Every entry under ``assets/``, hidden ones (half-stored uploads) included."""
    return sorted(p.relative_to(data / "assets").as_posix() for p in (data / "assets").rglob("*"))


@pytest.fixture()
def service(tmp_path):
    """Start a service that accepts uploads and runs nothing: ``start(limits)`` gives (client, data folder)."""

    def start(limits: Limits = Limits()):
        data = tmp_path / "data"
        cfg = ServiceConfig(data_dir=data, workers=0, dispatch=False, seed_examples=False, limits=limits)
        srv = ServerThread(create_app(cfg)).__enter__()
        client = httpx.Client(base_url=srv.url, timeout=60)
        started.append((srv, client))
        return client, data

    started: list = []
    yield start
    for srv, client in started:
        client.close()
        srv.__exit__(None, None, None)


def test_a_small_png_of_huge_dimensions_is_refused_from_its_header(service):
    client, data = service()
    body = huge_png(16384, 16000)
    assert len(body) < 4096  # a few KB on the wire, 4000 MiB decoded
    peak = _peak_rss()
    t = time.monotonic()
    r = client.put("/assets/maps/colour.png", content=body)
    seconds = time.monotonic() - t
    line = r.json()["detail"]
    assert r.status_code == 422 and "\n" not in line, line
    assert line.startswith("maps/colour.png: ") and "16384x16000" in line and "MiB limit" in line, line
    assert seconds < 10
    assert _peak_rss() - peak < 200 * MiB  # nothing was decoded in the service
    assert client.get("/health").status_code == 200
    assert _stored(data) == []
    assert client.put("/assets/maps/colour.png", content=small_png()).status_code == 201


def test_a_decode_that_exhausts_the_check_kills_only_the_child(service, monkeypatch):
    """Within the decode budget (2 GiB here) but over the child's memory (600 MiB): refused, the service lives."""
    monkeypatch.setattr(assets, "CHECK_BASE_BYTES", 600 * MiB)
    monkeypatch.setattr(assets, "CHECK_DECODED_FACTOR", 0)
    client, data = service(Limits(max_decoded_bytes=2 << 30))
    body = huge_png(8192, 8192, rows=8192)  # complete, 1 GiB as float32, ~260 KB on the wire
    assert len(body) < 400_000
    peak = _peak_rss()
    r = client.put("/assets/big.png", content=body)
    line = r.json()["detail"]
    assert r.status_code == 422 and "\n" not in line, line
    assert line.startswith("big.png: cannot read image:") and "600 MiB" in line, line
    assert _peak_rss() - peak < 200 * MiB
    assert client.get("/health").status_code == 200
    assert _stored(data) == []
    assert client.put("/assets/ok.png", content=small_png()).status_code == 201  # the next upload is checked as usual


def test_a_ply_that_claims_billions_of_vertices_is_refused(service):
    client, data = service()
    header = b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
    header += (
        b"property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    r = client.put("/assets/meshes/tree.ply", content=header + b"\0" * 64)
    assert 400 <= r.status_code < 500 and r.json()["detail"].startswith("meshes/tree.ply: "), r.text
    assert client.get("/health").status_code == 200
    assert _stored(data) == []


def test_the_check_is_bounded_in_time(tmp_path, monkeypatch):
    """A check that overruns its time is stopped and refused (here: a full decode allowed a tenth of a second)."""
    p = tmp_path / ".upload.x.png"
    p.write_bytes(huge_png(4096, 4096, rows=4096))
    with pytest.raises(assets.AssetError) as e:
        assets.check_isolated(p, "image", "x.png", 512 * MiB, timeout_s=0.1)
    assert e.value.status == 422 and "took over 0.1 s" in str(e.value)


def test_a_half_stored_upload_does_not_survive_a_killed_service(tmp_path):
    """``forest serve`` killed while it checks an upload leaves its temporary file; the next start removes it."""
    data = tmp_path / "data"
    serve = ServeProcess(data, "--workers", "0").start()
    body = huge_png(4096, 4096, rows=4096)  # within the budget: its check decodes 256 MiB, about a second
    try:
        sender = threading.Thread(
            target=lambda: _ignore(lambda: httpx.put(f"{serve.url}/assets/maps/big.png", content=body, timeout=30)),
            daemon=True,
        )
        sender.start()
        deadline = time.monotonic() + 30
        while not list((data / "assets").rglob(".upload.*")):
            assert time.monotonic() < deadline, "the upload never reached its check"
            time.sleep(0.005)
        serve.kill()
        sender.join(30)
        assert list((data / "assets").rglob(".upload.*")), "the killed service left nothing to clean"
    finally:
        serve.stop()
    serve = ServeProcess(data, "--workers", "0").start()
    try:
        assert "maps/big.png" not in {a["name"] for a in httpx.get(f"{serve.url}/assets").json()}
        assert not list((data / "assets").rglob(".upload.*"))
    finally:
        serve.stop()


def _ignore(fn) -> None:
    try:
        fn()
    except httpx.HTTPError:
        pass


def test_a_worker_blob_store_drops_what_a_killed_worker_half_wrote(tmp_path):
    from forest.service.transfer import BlobStore

    store = BlobStore(tmp_path / "w")
    old, fresh = store.blobs / ".blob.abc", store.blobs / ".blob.def"
    build = store.folders / ".build.xyz"
    for p in (old, fresh):
        p.write_bytes(b"half")
    build.mkdir()
    (build / "maps").mkdir()
    past = time.time() - 3600
    os.utime(old, (past, past))
    os.utime(build, (past, past))
    BlobStore(tmp_path / "w")  # a new worker in the same folder
    assert not old.exists() and not build.exists()
    assert fresh.exists()  # young: may belong to a live writer
