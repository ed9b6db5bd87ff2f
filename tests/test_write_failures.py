"""A write that fails part-way is one line, exit 2, and leaves no file behind.

OpenImageIO reports a short write (a full disk, a quota, a file size limit) only
through ``geterror()``: ``write_image`` and ``close`` return True, and the
truncated file used to be renamed into place and reported as written.  A frame
is its EXR and its PNG: when the PNG cannot be written the EXR goes too.
"""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_render_cli import SCENE

from forest.errors import ForestError

FOREST = [sys.executable, "-m", "forest.cli"]


class ShortWriter:
    """An OpenImageIO writer that, like the real one on a full disk, succeeds at every call but says why not."""

    def __init__(self, message: str):
        self.message = message

    def close(self) -> bool:
        return True

    def geterror(self) -> str:
        return self.message


def test_a_short_write_reported_only_by_geterror_raises_one_line(tmp_path):
    from forest.images import _finish

    tmp = tmp_path / ".f.forest-x-1.abc.tmp.png"
    with pytest.raises(ForestError) as err:
        _finish(
            ShortWriter(f"Write error at position 303709 of {tmp}, could only write 3491/8192 bytes\nmore"),
            tmp_path / "f.png",
            tmp,
        )
    assert (
        str(err.value)
        == f"{tmp_path / 'f.png'}: cannot write: Write error at position 303709 of {tmp_path / 'f.png'}, could only write 3491/8192 bytes"
    )
    _finish(ShortWriter(""), tmp_path / "f.png", tmp)  # no error: nothing raised


def test_a_render_past_the_file_size_limit_is_one_line_and_leaves_nothing(tmp_path):
    (tmp_path / "scene.toml").write_text(SCENE.format(render=""))
    limit = 16_000  # bytes: the frame's EXR (about 22 kB here) cannot be written whole

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    # The same render once without the limit first, so drjit's kernel cache holds its kernels: under the
    # limit drjit cannot write a new kernel to the cache and prints its own line about it.
    warm = subprocess.run([*FOREST, "render", tmp_path / "scene.toml", "-o", tmp_path / "warm" / "f.exr", "-q"],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert warm.returncode == 0, warm.stderr
    out = tmp_path / "out" / "f.exr"
    r = subprocess.run([*FOREST, "render", tmp_path / "scene.toml", "-o", out, "-q"], capture_output=True, text=True,
                       timeout=300, preexec_fn=small_files)  # fmt: skip
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"forest: error: {out}: cannot write: "), r.stderr
    assert "Traceback" not in r.stderr and sorted(p.name for p in out.parent.iterdir()) == []


def test_a_frame_whose_png_cannot_be_written_leaves_no_exr(tmp_path, monkeypatch):
    import forest.render.output as output
    from forest.camera import CameraState
    from forest.render.output import FrameImage

    def full(path, *a, **k):
        raise ForestError(f"{path}: cannot write: No space left on device")

    monkeypatch.setattr(output, "write_display", full)
    h, w = 4, 6
    image = FrameImage(
        rgb=np.full((h, w, 3), 0.2, np.float32), alpha=np.ones((h, w), np.float32), depth=np.ones((h, w), np.float32),
        id=np.full((h, w), -1.0, np.float32), species=np.full((h, w), -1.0, np.float32),
        camera=CameraState(np.array([0.0, 10.0, -10.0]), np.zeros(3), np.array([0.0, 1.0, 0.0]), 45.0),
        levels=np.zeros(0, np.int64),
    )  # fmt: skip
    exr, png = tmp_path / "f.exr", tmp_path / "f.png"
    with pytest.raises(ForestError, match="No space left on device"):
        output.write_frame(exr, png, image, species_names=[], near=0.1, far=100.0, view="AgX", exposure=0.0,
                           attributes={})  # fmt: skip
    assert sorted(Path(tmp_path).iterdir()) == []


def test_a_png_cut_short_by_the_file_size_limit_is_refused_not_truncated(tmp_path):
    """Without the check OpenImageIO wrote the first 300 kB of the PNG and the write 'succeeded'."""
    code = (
        "import resource, sys, numpy as np\n"
        "from forest.errors import ForestError\n"
        "from forest.imaging.view import write_display\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (300_000, 300_000))\n"
        "rgb = np.random.default_rng(0).random((800, 1200, 3)).astype(np.float32)\n"
        "try:\n"
        f"    write_display({str(tmp_path / 'f.png')!r}, rgb)\n"
        "except ForestError as e:\n"
        "    print(e); sys.exit(2)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stdout.startswith(f"{tmp_path / 'f.png'}: cannot write: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_a_full_disk_seen_as_a_failed_rename_is_named_for_what_it_is(tmp_path, monkeypatch):
    """USD saves through a temporary of its own: on a full disk the error that surfaces is the rename's EXDEV."""
    import errno

    from forest import atomic

    exdev = OSError(errno.EXDEV, "Invalid cross-device link")
    monkeypatch.setattr(atomic, "no_space", lambda _folder: True)
    assert (
        str(atomic._refused(tmp_path / "s.usda", exdev))
        == f"{tmp_path / 's.usda'}: cannot write: No space left on device"
    )
    monkeypatch.setattr(atomic, "no_space", lambda _folder: False)
    assert str(atomic._refused(tmp_path / "s.usda", exdev)).endswith("cannot write: Invalid cross-device link")


def test_errors_inside_an_output_folder_name_the_output_not_its_temporary(tmp_path):
    from forest.atomic import atomic_dir

    out = tmp_path / "rib"
    with pytest.raises(ForestError) as err, atomic_dir(out) as tmp:
        raise ForestError(f"{tmp / 'textures' / 'bark.tif'}: cannot write: No space left on device")
    assert str(err.value) == f"{out / 'textures' / 'bark.tif'}: cannot write: No space left on device"
    assert sorted(p.name for p in tmp_path.iterdir()) == []
