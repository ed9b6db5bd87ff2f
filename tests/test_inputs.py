"""Inputs that are not what they seem: a byte-order mark, a named pipe, a folder — each read or refused plainly."""

from __future__ import annotations

import os

import pytest

from forest.config import load_config
from forest.errors import ForestError
from forest.images import read_image
from forest.instances import InstanceSet

SCENE = '[terrain]\nflat = { size = 100.0 }\n[[species]]\nmodel = "broadleaf"\npercent = 100\n'


def test_a_config_with_a_utf8_byte_order_mark_loads(tmp_path):
    """Some Windows editors start UTF-8 files with a BOM; it was "Invalid statement"."""
    path = tmp_path / "scene.toml"
    path.write_bytes(b"\xef\xbb\xbf" + SCENE.encode())
    assert load_config(path).species[0].model == "broadleaf"


def test_a_named_pipe_as_an_input_is_named_and_never_read(tmp_path):
    """A FIFO given as a config, a map or an instance file: one line saying what it is (it was "not found"), and no
    read that would block."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for read in (load_config, lambda p: read_image(p, what="colour map"), InstanceSet.load):
        with pytest.raises(ForestError, match="not a regular file"):
            read(fifo)


# -- an image larger than the memory left ------------------------------------------------------------------------


def _grey_png(path, w: int = 128, h: int = 96):
    import numpy as np
    from conftest import write_png

    return write_png(path, np.full((h, w, 3), 0.5))


def test_an_image_over_the_memory_left_is_refused_from_its_header(tmp_path, monkeypatch):
    """A read whose decoded image (float32, every channel) would not fit the memory this process may still use is
    one line naming the file, its size decoded and the room (the cgroup limit that binds), before any decoding:
    a file whose pixel data is cut short is refused for its size, not for its damage."""
    from forest import memory
    from forest.memory import CgroupLimit, Room

    monkeypatch.delenv("FOREST_MEMORY_GB", raising=False)
    png = _grey_png(tmp_path / "colour.png")  # 128 × 96 × 3 × 4 bytes = 144 KiB decoded
    cut = tmp_path / "cut.png"
    data = png.read_bytes()
    cut.write_bytes(data[: data.index(b"IDAT") + 8])  # the header and the first bytes of the pixel data
    limit = CgroupLimit("/job.scope", 2, 1 << 30, (1 << 30) - (64 << 10))
    monkeypatch.setattr(memory, "memory_room", lambda: Room(limit.room, limit))
    for path in (png, cut):
        with pytest.raises(ForestError) as e:
            read_image(path, what="colour map")
        assert str(e.value) == (
            f"{path}: colour map is 128x96 with 3 channels, 144 KiB decoded, more than the 64 KiB of memory "
            "available (cgroup limit of 1.0 GiB on /job.scope)"
        )
    monkeypatch.setattr(memory, "memory_room", lambda: Room(144 << 10))  # just enough: read as before
    assert read_image(png).shape == (96, 128, 3)
    with pytest.raises(ForestError, match="cannot read image"):
        read_image(cut)
    monkeypatch.setattr(memory, "memory_room", lambda: None)  # nothing readable: no check
    assert read_image(png).shape == (96, 128, 3)


def test_the_cli_refuses_a_map_over_its_memory(tmp_path, monkeypatch):
    """The CLI's map reads follow the room it is given ($FOREST_MEMORY_GB, as its render check does): exit 2, one
    line naming the map, nothing written."""
    from conftest import run_forest

    _grey_png(tmp_path / "d.png", 256, 256)  # 768 KiB decoded
    cfg = tmp_path / "scene.toml"
    cfg.write_text('[terrain]\nflat = {}\n[maps]\ndensity = "d.png"\n' + SCENE.split("\n", 2)[2])
    out = tmp_path / "out" / "trees.npz"
    monkeypatch.setenv("FOREST_MEMORY_GB", str(256 / 2**20))  # 256 KiB
    r = run_forest("scatter", cfg, "-o", out)
    assert r.returncode == 2, (r.stdout, r.stderr)
    line = r.stderr.strip()
    assert "\n" not in line and "Traceback" not in line, line
    assert "d.png" in line and "256x256 with 3 channels, 768 KiB decoded, more than the 256 KiB of memory" in line
    assert not out.exists()
