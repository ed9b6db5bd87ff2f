"""Unbounded work from a small file (issue 28): generated tree variants and a render's memory, before any work.

A config naming thousands of seeded species (``broadleaf@0 … @9999``) once generated a mesh for
each on first use, for hours.  A scene draws on at most ``MAX_TREE_VARIANTS``; of those, the
ones the library has not built yet are counted before anything is scattered or built: over
``WARN_NEW_VARIANTS`` a warning says how long and how much disk, over ``MAX_NEW_VARIANTS``
(``$FOREST_ALLOW_GENERATE`` sets another number) the run is refused — the CLI with one line and
exit status 2, the job service with 422 at submission.  The service also refuses at submission a
render whose image alone needs more memory than its workers' machine has room for.
"""

from __future__ import annotations

import os
import subprocess
import sys
import warnings
from pathlib import Path

import httpx
import pytest
from conftest import write_scene

from forest import preflight
from forest.errors import ConfigError, ForestError, ForestWarning
from forest.library import open_library
from forest.service import jobs
from forest.service.app import ServiceConfig, create_app
from forest.service.jobs import Limits

from test_service_support import ServerThread, tiny_config

SCENE = """seed = 3
[terrain]
flat = {{ size = 100.0 }}
[scatter]
count = 40
{species}[camera]
position = [0.0, 30.0, -80.0]
target = [0.0, 0.0, 0.0]
[render]
width = 48
height = 27
spp = 2
"""


def seeded(seeds, individuals: int = 4) -> str:
    """``[[species]]`` tables of ``broadleaf@SEED``, each drawing ``individuals`` seeds from its own."""
    return "".join(f'[[species]]\nmodel = "broadleaf@{s}"\npercent = 1\nindividuals = {individuals}\n' for s in seeds)


def _config(folder: Path, species: str):
    from forest.config import load_config

    return load_config(write_scene(folder, SCENE.format(species=species)))


@pytest.fixture()
def library(tmp_path, monkeypatch):
    """An empty user library over the shipped presets: nothing generated is built yet."""
    monkeypatch.setenv("FOREST_LIBRARY", str(tmp_path / "lib"))
    monkeypatch.delenv(preflight.GENERATE_ENV, raising=False)
    return open_library()


def test_variants_to_generate_counts_distinct_unbuilt_seeds(tmp_path, library, monkeypatch):
    cfg = _config(tmp_path, seeded([100, 102], individuals=4))  # seeds 100–103 and 102–105: 6 distinct
    new = preflight.variants_to_generate(cfg, library)
    assert [label for _, label in new] == [f"broadleaf@{s}" for s in range(100, 106)]
    assert [f for f, _ in new] == ["species[0].model"] * 4 + ["species[1].model"] * 2
    built = {101, 104}  # as if these were in the cache
    real_get = type(library).get

    def get(self, name, *, seed=None, build=True):
        if not build and seed in built:
            return object()
        return real_get(self, name, seed=seed, build=build)

    monkeypatch.setattr(type(library), "get", get)
    assert [label for _, label in preflight.variants_to_generate(cfg, library)] == [
        "broadleaf@100",
        "broadleaf@102",
        "broadleaf@103",
        "broadleaf@105",
    ]


def test_more_new_variants_than_allowed_are_refused_before_any_work(tmp_path, library, monkeypatch):
    monkeypatch.setattr(preflight, "MAX_NEW_VARIANTS", 5)
    cfg = _config(tmp_path, seeded([0, 10], individuals=3))  # 6 new: the 6th belongs to species[1]
    with pytest.raises(ConfigError) as e:
        preflight.check_species(cfg, library)
    line = str(e.value)
    assert e.value.field == "species[1].model" and "\n" not in line
    assert "6 tree variants the library has not built yet" in line and "at most 5 a run" in line
    assert f"{preflight.GENERATE_ENV}=6" in line and "MB" in line
    assert not (tmp_path / "lib" / "cache").exists()  # nothing was generated
    monkeypatch.setenv(preflight.GENERATE_ENV, "6")
    assert preflight.check_generation(cfg, library) == 6


def test_a_warning_says_how_much_will_be_generated(tmp_path, library, monkeypatch):
    monkeypatch.setattr(preflight, "WARN_NEW_VARIANTS", 2)
    cfg = _config(tmp_path, seeded([0], individuals=3))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        preflight.check_species(cfg, library)
    said = [str(w.message) for w in caught if issubclass(w.category, ForestWarning)]
    assert len(said) == 1 and "3 tree variants are not built yet" in said[0] and "MB" in said[0], said
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        preflight.check_species(_config(tmp_path, seeded([0], individuals=2)), library)  # 2: no warning
    assert not [w for w in caught if issubclass(w.category, ForestWarning)]


def test_a_bad_allowance_is_one_line(monkeypatch):
    monkeypatch.setenv(preflight.GENERATE_ENV, "lots")
    with pytest.raises(ForestError, match=r"^\$FOREST_ALLOW_GENERATE: must be a whole number"):
        preflight.allowed_new_variants()


def test_the_cli_refuses_with_one_line_and_writes_nothing(tmp_path):
    folder = tmp_path / "case"
    write_scene(folder, SCENE.format(species=seeded(range(0, 60, 10), individuals=2)))  # 12 new variants
    env = {**os.environ, "FOREST_LIBRARY": str(tmp_path / "lib"), preflight.GENERATE_ENV: "11"}
    exe = Path(sys.executable).parent / "forest"
    r = subprocess.run(
        [str(exe), "scatter", "scene.toml", "-o", "trees.npz"],
        cwd=folder,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("forest: error: "), r.stderr
    assert "scene.toml: species[5].model: " in r.stderr
    assert "12 tree variants" in r.stderr
    assert sorted(p.name for p in folder.iterdir()) == ["scene.toml"]
    assert not (tmp_path / "lib" / "cache").exists()


# -- the job service ----------------------------------------------------------------------------------


@pytest.fixture()
def idle(tmp_path, monkeypatch):
    """Start a service that accepts jobs but starts none: ``start(limits)`` gives (client, data folder)."""
    monkeypatch.setattr(jobs, "_NAMES", jobs._Names())  # the library of this test's $FOREST_LIBRARY

    def start(limits: Limits = Limits()):
        data = tmp_path / "data"
        cfg = ServiceConfig(data_dir=data, workers=0, dispatch=False, seed_examples=False, limits=limits)
        srv = ServerThread(create_app(cfg)).__enter__()
        client = httpx.Client(base_url=srv.url, timeout=60)
        running.append((srv, client))
        return client, data

    running: list = []
    yield start
    for srv, client in running:
        client.close()
        srv.__exit__(None, None, None)


def _nothing_stored(client: httpx.Client, data: Path) -> bool:
    return client.get("/jobs").json()["counts"]["total"] == 0 and not any((data / "jobs").iterdir())


def test_the_service_refuses_too_many_new_variants_at_submission(idle, library, monkeypatch):
    monkeypatch.setattr(preflight, "MAX_NEW_VARIANTS", 3)
    client, data = idle()
    config = SCENE.format(species=seeded([0, 10], individuals=2))
    r = client.post("/jobs", json={"kind": "render", "config": config})
    line = r.json()["detail"]
    assert r.status_code == 422 and "\n" not in line, line
    assert line.startswith("config: species[1].model: the scene needs 4 tree variants"), line
    assert _nothing_stored(client, data)


def test_the_service_refuses_a_render_over_its_memory_room(idle):
    """The image's estimate (before any tree) against a tiny room: 422 with the estimate and the room."""
    client, data = idle(Limits(worker_memory_bytes=100 * 2**20))
    r = client.post("/jobs", json={"kind": "render", "config": tiny_config()})
    line = r.json()["detail"]
    assert r.status_code == 422 and "\n" not in line, line
    assert line.startswith("config: render.width/render.height: a 32x24 render needs about "), line
    assert "100.0 MiB available" in line
    r = client.post("/jobs", json={"kind": "flythrough", "config": tiny_config(), "settings": {"width": 64}})
    assert r.status_code == 422 and r.json()["detail"].startswith("settings.width: a 64x24 render"), r.text
    assert _nothing_stored(client, data)
    assert client.post("/jobs", json={"kind": "rib", "config": tiny_config()}).status_code == 202  # no render
    r = client.get("/jobs").json()
    assert r["counts"]["total"] == 1


def test_the_room_is_this_machines_for_local_workers_only(tmp_path, monkeypatch):
    """With no room given, the service reads its own (the local workers share its machine); tasks on a cluster
    are not checked against it."""
    from forest.memory import Room
    from forest.service.assets import DataDir

    monkeypatch.setattr(preflight, "memory_room", lambda: Room(50 * 2**20))
    req = jobs.JobRequest(kind="render", config=tiny_config())
    caps = {"render": True}
    with pytest.raises(jobs.RequestError, match=r"50\.0 MiB available"):
        jobs.prepare(req, DataDir(tmp_path / "data"), Limits(), caps)
    prep = jobs.prepare(req, DataDir(tmp_path / "data"), Limits(), caps, local=False)
    assert prep.task_specs
    prep = jobs.prepare(req, DataDir(tmp_path / "data"), Limits(check_memory=False), caps)
    assert prep.task_specs
