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
# The CLI's stderr is captured here, not a terminal: no "Progress: N%" lines among the messages tests read
# (tests/test_progress_lines.py sets the mode itself).
os.environ.setdefault("FOREST_PROGRESS", "none")


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


def seed_library_cache(root: Path, names, individuals: int = 1) -> list[str]:
    """Copy existing builds of the shipped species ``names`` (individuals ``0 … individuals − 1`` of each) into
    ``root/cache`` (a user library over the shipped presets, or a copy of the shipped library) where they match the
    current recipes; returns the labels copied.

    A build is looked up by its recipe hash (``cache/<name>[@seed]-<hash>``) in the user library that
    ``scripts/setup.sh`` builds and the suite's other tests use, then beside the checkout's ``library/``: a library
    seeded this way resolves exactly the species it would have built.  A build that is missing or stale is not
    copied and is built on first use as before.  For tests whose subject is not the build itself (building one
    individual takes seconds).
    """
    import shutil

    from forest.errors import ForestError
    from forest.library import open_library
    from forest.library.individuals import individual

    sources = [open_library(), open_library(ROOT / "library")]
    copied = []
    for name in names:
        for k in range(individuals):
            for lib in sources:
                try:
                    sp = individual(lib, name, k, build=False)
                except ForestError:
                    continue
                dest = Path(root) / "cache" / sp.folder.name
                if not dest.exists():
                    shutil.copytree(sp.folder, dest)
                copied.append(sp.folder.name)
                break
    return copied


@pytest.fixture
def flat_scene(tmp_path):
    """A 100 m flat terrain with one species, canopy structure off: returns a function(extra_toml) -> config path."""

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
            clumping = {{ strength = 0.0, clearings = 0.0 }}
            emergents = {{ fraction = 0.0 }}
        """
            + textwrap.dedent(sp)
            + textwrap.dedent(extra),
        )

    return make


def selfcheck_image(trees: bool = True) -> np.ndarray:
    """An image as forest's GPU self-check expects it (:mod:`forest.render.selfcheck`): 64×36, linear RGB and
    coverage, a lit ground with (``trees``) a block of green leaves on 10 % of it."""
    img = np.empty((36, 64, 4), np.float32)
    img[...] = (0.3, 0.28, 0.22, 1.0)
    if trees:
        img[10:25, 20:35, :3] = (0.15, 0.45, 0.1)
    return img


@pytest.fixture
def fake_gpu(monkeypatch, tmp_path):
    """A machine with an NVIDIA GPU whose self-check passes — both faked, so no CUDA and no child process.

    Returns a namespace tests change: ``name``, ``memory`` (MiB) and ``driver`` of the GPU (what ``nvidia-smi``
    would say), ``outcome`` (called as the check's child: returns its image or raises
    :class:`forest.render.selfcheck.SelfCheckError`); ``calls`` lists the checks run.  The results file goes to a
    fresh ``$FOREST_CACHE_DIR``, LLVM 19 is "found", and the process's memo of results starts empty.
    """
    from types import SimpleNamespace

    import forest.render.variant as variant
    from forest import runtime
    from forest.render import selfcheck

    state = SimpleNamespace(
        name="NVIDIA H100 80GB HBM3", memory=81559, driver="580.159.04", outcome=selfcheck_image, calls=[]
    )
    state.cache = tmp_path / "forest-cache"
    monkeypatch.setenv("FOREST_CACHE_DIR", str(state.cache))
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "0")  # restored afterwards, whoever changes it
    monkeypatch.setattr(runtime, "nvidia_driver", lambda: True)
    monkeypatch.setattr(runtime, "_gpu_info", lambda _device: runtime.GpuInfo(state.name, state.memory, state.driver))
    monkeypatch.setattr(variant, "find_llvm", lambda: "/usr/lib/llvm-19/lib/libLLVM-19.so")
    monkeypatch.setattr(selfcheck, "_memo", {})

    def launch(variant: str = "cuda_ad_rgb", *, timeout_s: float, command=None):
        state.calls.append((variant, timeout_s))
        return state.outcome()

    monkeypatch.setattr(selfcheck, "launch", launch)
    return state


#: A scene that scatters and renders in a second (scalar_rgb, 32×18, 1 spp): the CLI tests' subject.
TINY_SCENE = """
seed = 11
[terrain]
procedural = { size = 80.0, height = 6.0, resolution = 17 }
[scatter]
count = 12
[[species]]
model = "shrub"
percent = 100
scale = [2.0, 3.0]
[camera]
position = [0.0, 30.0, -60.0]
target = [0.0, 0.0, 0.0]
[render]
width = 32
height = 18
spp = 1
variant = "scalar_rgb"
"""


def run(argv) -> int:
    """Run ``forest argv`` in this process; its exit status."""
    import pytest

    from forest.cli import main

    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    return e.value.code or 0
