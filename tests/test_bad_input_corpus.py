"""The bad-input corpus (tests/bad_inputs/make_corpus.py): every user mistake is one line, exit 2, nothing written.

Each case runs the real ``forest`` command in its own folder and must:

* exit with status 2 within :data:`TIMEOUT` seconds (nothing hangs);
* print exactly one line on stderr, ``forest: error: …``, holding every expected
  word (the file or field at fault) — no traceback, no usage box, no stray line
  from libpng, OpenImageIO or Mitsuba;
* leave its folder exactly as it was (no output, no temporary, no empty folder,
  no input changed) and save no traceback as a bug report.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "bad_inputs"))

import make_corpus

TIMEOUT = 120
MIN_CASES = 60


@pytest.fixture(scope="session")
def corpus(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("corpus")
    make_corpus.build(root)
    return root


def _case_names(*kinds: str) -> list[str]:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        return [c.name for c in make_corpus.cases(Path(d)) if not kinds or c.kind in kinds]


NAMES = _case_names()


def _snapshot(folder: Path) -> dict[str, str]:
    """Every entry under ``folder`` (files by content hash, folders as such, hidden ones included)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        out[rel] = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
    return out


def _forest() -> list[str]:
    exe = Path(sys.executable).parent / "forest"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "forest.cli"]


def test_the_corpus_is_large_and_covers_every_class():
    assert len(NAMES) >= MIN_CASES
    with __import__("tempfile").TemporaryDirectory() as d:
        kinds = {c.kind for c in make_corpus.cases(Path(d))}
    assert kinds >= {"output", "input", "species", "value", "memory", "option", "library", "reference"}


@pytest.mark.parametrize("name", NAMES)
def test_bad_input(corpus, tmp_path, name):
    src = corpus / name
    meta = json.loads((src / "case.json").read_text())
    work = tmp_path / "case"
    shutil.copytree(src, work, symlinks=True)
    (work / "case.json").unlink()
    before = _snapshot(work)
    state = tmp_path / "state"
    env = {**os.environ, "XDG_STATE_HOME": str(state), "FOREST_MEMORY_GB": make_corpus.MEMORY_GB, **meta["env"]}
    env.pop("FOREST_DEBUG", None)
    r = subprocess.run([*_forest(), *meta["argv"]], cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(lines) == 1, r.stderr
    line = lines[0]
    assert line.startswith("forest: error: "), line
    assert "Traceback" not in r.stderr and "Usage:" not in r.stderr
    for word in meta["expect"]:
        assert word in line, (word, line)
    assert _snapshot(work) == before, "the case's folder changed"
    assert not (state / "forest" / "tracebacks").exists(), "a user's mistake was saved as a bug"


@pytest.mark.parametrize("name", _case_names("input", "species", "value"))
def test_a_mistake_in_an_input_is_one_line_in_a_farms_log_too(corpus, tmp_path, name):
    """With progress as a render farm reads it (``FOREST_PROGRESS=lines``) a mistake in a file, a species or a
    value is still the one error line: the species, the terrain, the maps and the meshes are read before the
    first progress line (a truncated map had left ``Progress: 0% scatter: terrain`` above its error)."""
    src = corpus / name
    meta = json.loads((src / "case.json").read_text())
    work = tmp_path / "case"
    shutil.copytree(src, work, symlinks=True)
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state"), "FOREST_MEMORY_GB": make_corpus.MEMORY_GB}
    env.update({**meta["env"], "FOREST_PROGRESS": "lines"})
    r = subprocess.run([*_forest(), *meta["argv"]], cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [r.stderr.strip()], r.stderr
