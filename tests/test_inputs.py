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
