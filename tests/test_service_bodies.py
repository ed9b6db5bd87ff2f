"""Malformed request bodies get a short, specific 4xx that never echoes the body."""

from __future__ import annotations

import json

import httpx
import pytest

from forest.service.app import ServiceConfig, create_app

from test_service_support import ServerThread

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    cfg = ServiceConfig(data_dir=tmp_path_factory.mktemp("bodies") / "data", workers=0, dispatch=False)
    with ServerThread(create_app(cfg)) as srv, httpx.Client(base_url=srv.url, timeout=30) as c:
        yield c


SECRET = b"SECRET-" + b"A" * 4000


@pytest.mark.parametrize(
    "body,content_type,status,detail",
    [
        (SECRET, "text/plain", 415, "body: must be JSON sent as application/json, got text/plain"),
        (b"[" * 50_000 + b"]" * 50_000, "application/json", 400, "body: JSON nested too deeply"),
        (b'{"kind": "render", "config": "\xff\xfe"}', "application/json", 400,
         "body: not UTF-8 text (byte 0xff at position 30)"),
        (b"{SECRET", "application/json", 422, "body: invalid JSON: Expecting property name enclosed in double quotes"),
        (json.dumps(["SECRET" * 800]).encode(), "application/json", 422, "must be a table, got a list of 1 item"),
        (json.dumps({"kind": "render", "config": "demo", "settings": {"spp": "SECRET" * 800}}).encode(),
         "application/json", 422, "settings.spp: must be a whole number, got a 4,800-character string"),
    ],
)  # fmt: skip
def test_malformed_bodies_are_answered_in_one_short_line(client, body, content_type, status, detail):
    r = client.post("/jobs", content=body, headers={"content-type": content_type})
    assert r.status_code == status, r.text
    assert r.json() == {"detail": detail}
    assert "SECRET" not in r.text and len(r.text) < 200
