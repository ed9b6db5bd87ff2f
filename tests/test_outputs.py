"""The output policy: an output never replaces a device, pipe or socket, never one of the command's own inputs,
and a killed run's temporaries are cleaned by the next write of the same output."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import run_forest

from forest.atomic import _owner, atomic_path

SCENE = """
seed = 3
[terrain]
flat = { size = 100.0 }
[scatter]
count = 40
[[species]]
model = "broadleaf"
percent = 100
[camera]
position = [0.0, 30.0, -80.0]
target = [0.0, 0.0, 0.0]
[render]
width = 48
height = 27
spp = 2
"""


def _one_line(r: subprocess.CompletedProcess) -> str:
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, (r.returncode, r.stderr)
    return lines[0]


@pytest.mark.parametrize("command", [["schema"], ["render", "scene.toml"]])
def test_a_named_pipe_is_never_replaced(tmp_path, command):
    """(Run as root, ``forest schema -o /dev/null`` used to turn the device into a JSON file.)"""
    (tmp_path / "scene.toml").write_text(SCENE)
    name = {"schema": "out.json", "render": "out.exr", "scatter": "out.npz"}[command[0]]
    os.mkfifo(tmp_path / name)
    line = _one_line(run_forest(*command, "-o", name, cwd=tmp_path))
    assert "named pipe" in line and name in line
    assert stat.S_ISFIFO(os.stat(tmp_path / name).st_mode)


def test_an_output_that_is_an_input_through_a_hard_link_is_refused(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE)
    os.link(tmp_path / "scene.toml", tmp_path / "scene.usda")  # the same file under an export's name
    line = _one_line(run_forest("export", "usd", "scene.toml", "-o", "scene.usda", cwd=tmp_path))
    assert "is an input" in line and "scene.usda" in line
    assert (tmp_path / "scene.toml").read_text() == SCENE


def test_match_never_writes_over_its_own_scene(tmp_path):
    from forest.images import write_image

    (tmp_path / "scene.toml").write_text(SCENE)
    write_image(tmp_path / "ref.png", __import__("numpy").full((27, 48, 3), 0.3, "float32"))
    line = _one_line(run_forest("match", "scene.toml", "--reference", "ref.png", "-o", ".", cwd=tmp_path))
    assert "scene.toml" in line and "is an input" in line
    assert (tmp_path / "scene.toml").read_text() == SCENE
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ref.png", "scene.toml"]


def test_a_killed_runs_temporaries_are_removed_by_the_next_write(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(dead.stdout)  # a process that has exited
    host = _owner().rsplit("-", 1)[0]
    stale = tmp_path / f".frame.{host}-{dead_pid}.abc123.tmp.exr"
    live = tmp_path / f".frame.{_owner()}.def456.tmp.exr"  # this process's own: still being written
    other_host = tmp_path / f".frame.forest-elsewhere-{dead_pid}.ghi789.tmp.exr"
    other_name = tmp_path / f".trees.{host}-{dead_pid}.jkl012.tmp.npz"
    for p in (stale, live, other_host, other_name):
        p.write_bytes(b"half")
    with atomic_path(tmp_path / "frame.exr") as tmp:
        Path(tmp).write_bytes(b"whole")
    assert (tmp_path / "frame.exr").read_bytes() == b"whole"
    assert not stale.exists()
    assert live.exists() and other_host.exists() and other_name.exists()


def test_serve_on_a_taken_port_is_one_line_and_creates_nothing(tmp_path):
    """Before, the banner was printed, then uvicorn's error, exit 3, and a new data folder was left behind."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = run_forest("serve", "--port", str(port), "--data", "data", cwd=tmp_path, timeout=60)
    line = _one_line(r)
    assert f"--port {port}" in line and "cannot listen" in line
    assert not (tmp_path / "data").exists()
