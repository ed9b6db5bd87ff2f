"""The example scenes shipped with forest (``configs/`` in a checkout, ``forest.examples`` when installed)."""

from __future__ import annotations

import shutil
from importlib.resources import files
from pathlib import Path

from .errors import ForestError


def examples_root() -> Path:
    """The folder holding the example configs and their ``maps/``."""
    return Path(str(files("forest.examples")))


def example_names() -> list[str]:
    """Names of the example scenes (config file stems), sorted."""
    return sorted(p.stem for p in examples_root().glob("*.toml"))


def example_path(name: str) -> Path:
    """The config file of example ``name``; one clear line when there is none."""
    p = examples_root() / f"{name}.toml"
    if not p.is_file():
        raise ForestError(f"unknown example {name!r}; examples: {', '.join(example_names())}")
    return p


def example_summary(name: str) -> str:
    """The first comment line of an example's config, without the ``#``."""
    for line in example_path(name).read_text().splitlines():
        if line.startswith("#"):
            return line.lstrip("# ").strip()
    return ""


def copy_example(name: str, folder: str | Path) -> Path:
    """Copy example ``name`` and every file its config names into ``folder``; return the new config's path.

    Relative paths keep their place under ``folder`` (``maps/…`` stays ``maps/…``),
    so the copy renders unchanged.  Existing files are not overwritten.
    """
    from .config import load_config, referenced_files

    src = example_path(name)
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ForestError(f"{folder}: exists and is not a folder")
    config = load_config(src)
    todo = [(src, folder / src.name)]
    for f in referenced_files(config):
        rel = f.relative_to(src.parent) if f.is_relative_to(src.parent) else Path(f.name)
        todo.append((f, folder / rel))
    clash = [dst for _, dst in todo if dst.exists()]
    if clash:
        raise ForestError(f"{clash[0]}: already exists; copy into an empty folder")
    for s, d in todo:
        d.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(s, d)
    return folder / src.name
