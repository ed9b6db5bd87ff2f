"""Provenance of an InstanceSet: the input files it was scattered from, by content.

A scatter records in the InstanceSet's metadata, under ``inputs``, the SHA-256
of every file it read — the terrain (``terrain.heightmap`` or ``terrain.mesh``)
and the maps (``maps.presence``, ``density``, ``colour``, ``partition`` and,
for the ecosystem method, ``moisture``) — keyed by the config field, with the
path as the config named it::

    "inputs": {"maps.colour": {"file": "maps/colour.png", "sha256": "9f2c…"}, …}

The species models list is the set's ``species_names``.  A saved set is only
right for a config whose species and placement inputs are the ones it was
scattered from: :func:`check_provenance` compares them when a set is loaded for
a config (``--instances``) and refuses a mismatch with one line naming the
field.  The colour map is recorded but not refused: it only tints, and a Scene
built with a repainted map (an artist's edit, look-dev's fitted map) takes the
trees' tints from the new map (:mod:`forest.scene`).
Contents are compared, not paths or times: a map moved or touched is still
the same map.  Sets written before inputs were recorded load with a
:class:`~forest.errors.ForestWarning`.

The species list compared is the InstanceSet's ``species_names``: the
``[[species]]`` models then the ``[[ground_cover]]`` ones
(:func:`~forest.scatter.models.scatter_models`).  Ground cover is placed
around the camera path, so a set with ground cover also records the digest of
``[camera]`` and ``[[ground_cover]]`` (``meta["ground_cover"]``,
:func:`cover_digest`) and is refused for a config whose camera path or cover
settings differ.  Look settings are not inputs: the ``individual`` column is
folded into the individuals a config asks for and the tints are recomputed by
the Scene (:mod:`forest.scene`).
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path

from ..config import Config
from ..errors import ConfigError, ForestError, ForestWarning
from ..instances import InstanceSet
from .models import scatter_models

INPUT_FIELDS = (
    "terrain.heightmap",
    "terrain.mesh",
    "maps.presence",
    "maps.density",
    "maps.colour",
    "maps.partition",
    "maps.moisture",
)

#: The inputs that decide where trees stand (a change refuses a saved set); the colour map only tints.
PLACEMENT_FIELDS = tuple(f for f in INPUT_FIELDS if f != "maps.colour")


def scatter_inputs(config: Config) -> dict[str, Path]:
    """The files a scatter of ``config`` reads, by config field (in :data:`INPUT_FIELDS` order)."""
    t, m = config.terrain, config.maps
    files = {
        "terrain.heightmap": t.heightmap,
        "terrain.mesh": t.mesh,
        "maps.presence": m.presence,
        "maps.density": m.density,
        "maps.colour": m.colour,
        "maps.partition": m.partition,
        "maps.moisture": m.moisture if config.scatter.method == "ecosystem" else None,
    }
    return {k: Path(p) for k, p in files.items() if p is not None}


def file_sha256(path: Path, field: str, config: Config) -> str:
    """SHA-256 (hex) of the file at ``path``; an unreadable file is a ``ConfigError`` on ``field``."""
    try:
        with open(path, "rb") as f:
            return hashlib.file_digest(f, "sha256").hexdigest()
    except OSError as e:
        raise ConfigError(config.path, field, f"cannot read {path}: {e.strerror or e}") from None


def shown(path: Path, config: Config) -> str:
    """``path`` as a user reads it: relative to the config's folder where it can be."""
    try:
        return Path(os.path.relpath(path, config.base_dir)).as_posix()
    except ValueError:  # another drive
        return str(path)


def input_hashes(config: Config) -> dict[str, dict[str, str]]:
    """``{field: {"file": path, "sha256": hex}}`` for every file a scatter of ``config`` reads."""
    return {
        field: {"file": shown(p, config), "sha256": file_sha256(p, field, config)}
        for field, p in scatter_inputs(config).items()
    }


def check_provenance(inst: InstanceSet, config: Config, source: str | Path) -> None:
    """Refuse ``inst`` (loaded from ``source``) for ``config`` unless it was scattered from the same inputs.

    Raises :class:`~forest.errors.ConfigError` (one line: the config, the field,
    what differs) when the species models differ, or when an input file's
    content changed, was added or was dropped.  Warns, and accepts, when the set
    records no inputs (written before they were recorded).
    """
    expected = scatter_models(config)
    if list(inst.species_names) != expected:
        raise ConfigError(
            config.path,
            "ground_cover"
            if config.model.ground_cover and len(inst.species_names) > len(config.species)
            else "species",
            f"models {expected} differ from {list(inst.species_names)} that {source} was scattered with; scatter again",
        )
    if cover_digest(config) != inst.meta.get("ground_cover"):
        raise ConfigError(
            config.path,
            "ground_cover",
            f"the camera path or [[ground_cover]] differ from those {source} was scattered with "
            "(ground cover grows around the camera); scatter again",
        )
    if placed_digest(config) != inst.meta.get("placed"):
        raise ConfigError(
            config.path, "tree", f"the [[tree]] entries differ from those {source} was scattered with; scatter again"
        )
    recorded = inst.meta.get("inputs")
    if recorded is None:
        warnings.warn(
            ForestWarning(
                f"{source} records no input hashes (written by an older forest): its maps are not checked "
                f"against {config.path.name if config.path else 'the config'}; scatter again to record them"
            ),
            stacklevel=2,
        )
        return
    if not isinstance(recorded, dict):
        raise ForestError(f"{source}: not a forest instance file (meta.inputs is not a table)")
    current = scatter_inputs(config)
    for field in PLACEMENT_FIELDS:
        was, now = recorded.get(field), current.get(field)
        if was is None and now is None:
            continue
        if was is None:
            assert now is not None
            msg = f"{shown(now, config)} was not used when {source} was scattered"
        elif now is None:
            msg = f"{source} was scattered with {was.get('file')}, which this config does not use"
        elif file_sha256(now, field, config) != was.get("sha256"):
            msg = f"{shown(now, config)} changed since {source} was scattered"
        else:
            continue
        raise ConfigError(config.path, field, msg + "; scatter again")


def cover_digest(config: Config) -> str | None:
    """SHA-256 of the ``[camera]`` and ``[[ground_cover]]`` settings that place ground cover; None without any."""
    if not config.model.ground_cover:
        return None
    data = {
        "camera": config.camera.model_dump(mode="json"),
        "ground_cover": [c.model_dump(mode="json") for c in config.model.ground_cover],
    }
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def placed_digest(config: Config) -> str | None:
    """SHA-256 of the ``[[tree]]`` entries (trees placed by hand); None without any."""
    if not config.model.tree:
        return None
    data = [t.model_dump(mode="json") for t in config.model.tree]
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()
