"""Shared test helpers: tiny maps, scene configs and an in-process CLI runner."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

os.environ.setdefault("OPENIMAGEIO_THREADS", "1")


def write_png(path: Path, img: np.ndarray, bits: int = 8) -> Path:
    """Write a float image in [0, 1] ((H, W) or (H, W, C)) as an 8/16-bit PNG, values as given."""
    import OpenImageIO as oiio

    img = np.clip(np.asarray(img, dtype=np.float64), 0, 1)
    if img.ndim == 2:
        img = img[..., None]
    fmt = oiio.UINT16 if bits == 16 else oiio.UINT8
    data = np.round(img * (65535 if bits == 16 else 255)).astype(np.uint16 if bits == 16 else np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], fmt))
    out.write_image(data)
    out.close()
    return path


def write_scene(folder: Path, text: str, name: str = "scene.toml") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / name
    p.write_text(textwrap.dedent(text))
    return p


def run_forest(*args: str, cwd: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run the real ``forest`` CLI in a subprocess; returns the completed process."""
    exe = Path(sys.executable).parent / "forest"
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "forest.cli"]
    return subprocess.run(cmd + [str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def flat_scene(tmp_path):
    """A 100 m flat terrain with one species: returns a function(extra_toml) -> config path."""

    def make(extra: str = "", count: int = 2000, species: str | None = None) -> Path:
        sp = (
            species
            if species is not None
            else """
            [[species]]
            model = "broadleaf"
            percent = 100
        """
        )
        return write_scene(
            tmp_path,
            f"""
            seed = 3
            [terrain]
            flat = {{ size = 100.0 }}
            [scatter]
            count = {count}
        """
            + textwrap.dedent(sp)
            + textwrap.dedent(extra),
        )

    return make
