"""The bad-input corpus through the job service: every mistake a service user can make answers 4xx.

Each case of ``tests/bad_inputs/make_corpus.py`` that a user of ``forest serve`` can
make is replayed as that user would: its files are uploaded with ``PUT /assets/<name>``
(the config names them by the same relative paths) and the job is submitted with
``POST /jobs`` carrying the case's config text unchanged; the CLI's flags become the
request's settings (``--spp`` → ``settings.spp``, ``--reference`` → ``settings.reference``,
``--frames`` → a ``flythrough`` job …).  ``forest scatter`` cases are submitted as
``render`` jobs: the service has no scatter job, and a render scatters first, so the
same mistake in the config reaches the same check.

For every case the test asserts:

* every answer is 4xx, never 5xx — an upload that is refused (a truncated or NaN image,
  an empty file, a mesh without area) answers 4xx and stores nothing, and the job that
  names it is then refused as well (its asset is missing);
* the refusal is one line holding the words the CLI's line holds, in the service's
  terms: a CLI flag becomes its JSON field (``--spp`` → ``settings.spp``), the config
  file becomes ``config``, and when an upload is refused the config field (which an
  upload does not know) becomes the uploaded file's name;
* a refused job leaves nothing behind: the job count, the job folders and the assets
  folder are as they were (a refused upload stores nothing, not even a temporary).

A job is never accepted (202) for a mistake the service can see at submission.  The
only mistakes found when the job runs are those only the renderer can see
(:data:`AT_RUN`): such a job must end ``failed`` after one attempt (a user's mistake is
not retried), with the CLI's words in its error, and no output.

Skipped, by ``kind`` of the corpus (the service has no such input):

* ``output`` — output paths: a job's outputs go into its own folder of the service's
  data folder, never to a path the user names;
* ``library`` — ``forest library add|build|preview``: the service has no library route;
* ``option`` cases that are CLI syntax (a misspelled command or flag, a missing
  ``--output``, ``library``/``examples`` options); the option *values* that are job
  settings (``--spp 0``, ``--frames 9-2``, ``--variant metal``, ``--count -5``,
  ``--width abc``) are run;
* ``memory`` cases about the CLI's environment (``FOREST_MEMORY_GB``) or its output
  disk; the render size cases are run: the service refuses them by its own size
  limit (:class:`forest.service.jobs.Limits`) instead of the machine's memory, so its
  line says "service limit" where the CLI's says what "fits";
* ``input`` cases about files the service never reads from the user: ``--instances``
  (a job cannot name a saved InstanceSet), a missing or non-UTF-8 config file (the
  config is JSON text, always Unicode);
* ``reference`` cases about ``--mask`` (a match job has no mask setting).
"""

from __future__ import annotations

import re
import shutil
import sys
import tempfile
from pathlib import Path

import httpx
import pytest

from forest.service.app import ServiceConfig, create_app

from test_service_support import ServerThread, wait_job

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "bad_inputs"))

import make_corpus

#: CLI flag → the request's JSON field.
FLAG_FIELDS = {
    "--spp": "settings.spp",
    "--width": "settings.width",
    "--height": "settings.height",
    "--width/--height": "settings.width/settings.height",
    "--frames": "settings.frames",
    "--variant": "settings.variant",
    "--count": "settings.count",
    "--seed": "settings.seed",
    "--reference": "settings.reference",
    "--iterations": "settings.iterations",
    "--resolution": "settings.resolution",
    "--params": "settings.params",
    "--mode": "settings.mode",
}
#: Flags that name a file (the service names it by the uploaded file's name).
FILE_FLAGS = {"--reference"}
#: Option cases that are job settings (the other option cases are CLI syntax).
SETTING_OPTIONS = {
    "spp_zero",
    "width_not_a_number",
    "frames_reversed",
    "frames_garbage",
    "variant_unknown",
    "count_negative_flag",
}
#: Memory cases the service sees (by its size limit).
SIZE_CASES = {"render_16384_square", "render_16384_flags"}
#: Words of the CLI's line that belong to a check the service makes differently, and the service's words.
SERVICE_WORDS = {"fits": "service limit"}
#: Mistakes only the renderer can see: Mitsuba's own loader refuses an EXR it cannot map to RGB.
AT_RUN = {"envmap_two_channels"}
#: The config's fields named by a bare word (the others are dotted or indexed).
BARE_FIELDS = {"species"}


def skip_reason(case: make_corpus.Case) -> str | None:
    """Why a service user cannot make this mistake (None: they can)."""
    if case.kind == "output":
        return "output paths: the service writes into the job's own folder"
    if case.kind == "library":
        return "the service has no library route"
    if case.kind == "option" and case.name not in SETTING_OPTIONS:
        return "CLI syntax"
    if case.kind == "memory" and case.name not in SIZE_CASES:
        return "the CLI's environment or output disk"
    if "--instances" in case.argv:
        return "a job cannot name a saved InstanceSet"
    if case.name in ("config_missing", "config_not_utf8", "config_is_a_folder"):
        return "the config is JSON text"
    if "--mask" in case.argv:
        return "a match job has no mask setting"
    if case.argv[0] not in ("render", "scatter", "match"):
        return "not a job"
    return None


def _all_cases() -> list[make_corpus.Case]:
    with tempfile.TemporaryDirectory() as d:
        return make_corpus.cases(Path(d))


CASES = {c.name: c for c in _all_cases()}
SERVICE_CASES = sorted(n for n, c in CASES.items() if skip_reason(c) is None)


def request_of(case: make_corpus.Case) -> dict:
    """The ``POST /jobs`` body a service user sends for the case's command line."""
    argv = case.argv
    settings: dict = {}
    kind = {"render": "render", "scatter": "render", "match": "match"}[argv[0]]
    config = case.files["scene.toml"]
    assert isinstance(config, str)
    i = 2
    while i < len(argv):
        flag = argv[i]
        value = argv[i + 1] if i + 1 < len(argv) else None
        i += 2
        if flag in ("-o", "--output"):
            continue
        key = FLAG_FIELDS[flag].split(".", 1)[1]
        if key == "frames":
            kind = "flythrough"
        if key == "params":
            settings[key] = value.split(",") if value else value
        elif (
            key in ("spp", "width", "height", "count", "seed", "iterations", "resolution")
            and value.lstrip("-").isdigit()
        ):
            settings[key] = int(value)
        else:
            settings[key] = value
    return {"kind": kind, "config": config, "settings": settings}


def uploads_of(case: make_corpus.Case) -> dict[str, bytes]:
    """The case's files other than its config: what the user uploads."""
    out = {}
    for rel, content in case.files.items():
        if rel == "scene.toml":
            continue
        out[rel] = content if isinstance(content, bytes) else str(content).encode()
    return out


def is_field(word: str) -> bool:
    return word in BARE_FIELDS or bool(re.fullmatch(r"[a-z_]+(\[\d+\])?([./][a-z_]+(\[\d+\])?)+", word))


def service_words(case: make_corpus.Case, *, refused_upload: str | None) -> list[str]:
    """The case's expected CLI words in the service's terms (see the module docstring)."""
    out = []
    for word in case.expect:
        if word in FILE_FLAGS and refused_upload is not None:
            word = refused_upload  # an upload does not know which setting will name it
        elif word in FLAG_FIELDS:
            word = FLAG_FIELDS[word]
        elif word == "scene.toml":
            word = "config"
        elif word in SERVICE_WORDS:
            word = SERVICE_WORDS[word]
        elif is_field(word) and case.name in SIZE_CASES:
            word = word.replace("render.", "config: render.", 1)
        elif is_field(word) and refused_upload is not None:
            word = refused_upload  # an upload does not know which field will name it
        out.append(word)
    return out


def _one_line(detail: object) -> str:
    assert isinstance(detail, str), detail
    assert "\n" not in detail.strip(), detail
    assert "Traceback" not in detail
    return detail


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    data = tmp_path_factory.mktemp("svc") / "data"
    app = create_app(ServiceConfig(data_dir=data, workers=1, seed_examples=False, worker_idle_s=3600.0))
    with ServerThread(app) as srv, httpx.Client(base_url=srv.url, timeout=60) as client:
        yield client, data


def _state(data: Path, client: httpx.Client) -> tuple:
    counts = client.get("/jobs").json()["counts"]
    jobs = sorted(p.name for p in (data / "jobs").iterdir())
    assets = sorted(p.relative_to(data / "assets").as_posix() for p in (data / "assets").rglob("*"))
    return counts["total"], jobs, assets


def test_the_service_sees_most_of_the_corpus():
    kinds = {CASES[n].kind for n in SERVICE_CASES}
    assert len(SERVICE_CASES) >= 50
    assert kinds >= {"input", "species", "value", "memory", "option", "reference"}


@pytest.mark.parametrize("name", SERVICE_CASES)
def test_bad_input_through_the_service(server, name):
    client, data = server
    case = CASES[name]
    shutil.rmtree(data / "assets")
    (data / "assets").mkdir()
    refused: str | None = None
    for rel, content in uploads_of(case).items():
        before = _state(data, client)
        r = client.put(f"/assets/{rel}", content=content)
        assert r.status_code < 500, (rel, r.status_code, r.text)
        if r.status_code >= 400:
            refused = rel
            line = _one_line(r.json()["detail"])
            for word in service_words(case, refused_upload=rel):
                assert word in line, (word, line)
            assert _state(data, client) == before, "a refused upload stored something"
    body = request_of(case)
    before = _state(data, client)
    r = client.post("/jobs", json=body)
    assert r.status_code < 500, (r.status_code, r.text)
    if r.status_code == 202:
        assert refused is None, f"accepted a job naming the refused upload {refused}"
        assert name in AT_RUN, f"accepted a job with a mistake the service can see at submission: {r.text}"
        job = wait_job(client, r.json()["id"], timeout=120)
        assert job["state"] == "failed", job
        line = _one_line(job["error"])
        for word in service_words(case, refused_upload=None):
            assert word in line, (word, line)
        assert all(t["attempt"] == 1 for t in job["tasks"]), "a user's mistake was retried"
        assert not any((data / "jobs" / job["id"] / "out").rglob("*.exr")), "a failed job wrote an image"
        return
    assert name not in AT_RUN, "now refused at submission: move it out of AT_RUN"
    assert 400 <= r.status_code < 500
    line = _one_line(r.json()["detail"])
    if refused is None:
        for word in service_words(case, refused_upload=None):
            assert word in line, (word, line)
    else:
        assert refused in line and "not found" in line, line
    assert _state(data, client) == before, "a refused job left something in the store or the data folder"
