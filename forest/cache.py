"""forest's cache folder on this machine: processed sky maps, the GPU self-check's results, solid leaf cards.

Everything in it is derived from other files and can be deleted at any time; it is rebuilt on use.
``$FOREST_CACHE_DIR`` names it; otherwise it is ``forest`` in the user's cache folder
(:func:`platformdirs.user_cache_path`, ``~/.cache/forest`` on Linux).
"""

from __future__ import annotations

import os
from pathlib import Path

#: The environment variable that names the cache folder.
CACHE_ENV = "FOREST_CACHE_DIR"


def cache_root() -> Path:
    """``$FOREST_CACHE_DIR``, else ``forest`` in the user cache folder."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_path("forest"))


def cache_folder(name: str) -> Path:
    """The sub-folder ``name`` of :func:`cache_root` (not created here)."""
    return cache_root() / name
