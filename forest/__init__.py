"""forest: grow, render, export and look-dev very large forests."""

from __future__ import annotations

import functools
from pathlib import Path

__all__ = ["__version__", "package_version"]


@functools.cache
def package_version() -> str:
    """forest's version: the installed distribution's, else (a source checkout that is not installed) the one in
    ``pyproject.toml`` beside the package, else ``0+unknown``."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("forest")
    except PackageNotFoundError:
        pass
    import tomllib

    try:
        project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())["project"]
        if project.get("name") == "forest":
            return str(project["version"])
    except (OSError, ValueError, KeyError, TypeError):
        pass
    return "0+unknown"


def __getattr__(name: str) -> str:
    """``forest.__version__``, looked up when first asked for (importing forest stays cheap)."""
    if name == "__version__":
        return package_version()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
