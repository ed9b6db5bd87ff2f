"""Scene configuration: one TOML file, validated against one schema, field by field.

:func:`load_config` reads a file and returns a :class:`Config` — the validated
:class:`~forest.config.schema.SceneConfig` plus where it came from.  Every
problem raises :class:`~forest.errors.ConfigError` naming the file and the
dotted field, e.g. ``scene.toml: species[1].percent: must be <= 100, got 140``,
before any work is done: the whole file is validated when it is read.

Relative paths in a config are relative to the config file's folder.
:func:`apply_overrides` is the one way the CLI's flags, the service's job
settings and look-dev's fitted values change a config.
"""

from __future__ import annotations

import copy
import re
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from ..errors import ConfigError, ForestError
from .messages import first_error
from .schema import (
    MAX_IMAGE_SIDE,
    MAX_TREES,
    CameraConfig,
    CameraKey,
    EcosystemConfig,
    ExportConfig,
    LightsConfig,
    LodConfig,
    LookdevConfig,
    MapsConfig,
    RenderConfig,
    ScatterConfig,
    SceneConfig,
    SkyConfig,
    SpeciesConfig,
    SunConfig,
    SunskyConfig,
    TerrainConfig,
    WindConfig,
    file_fields,
)

#: Largest scene file read (the CLI and the service refuse bigger ones alike).
MAX_CONFIG_BYTES = 1 << 20
#: Deepest nesting of tables and arrays accepted in a scene file.
MAX_DEPTH = 32


@dataclass(frozen=True)
class Partition:
    """A region of the partition map: its 8-bit sRGB label colour and name."""

    colour: tuple[int, int, int]
    name: str


class Config:
    """A validated scene config: the :class:`SceneConfig` sections plus the file it came from.

    ``data`` is the TOML as read (after overrides); ``path`` the file (None for
    text given directly, e.g. by the service); ``base_dir`` the folder relative
    paths are resolved against.
    """

    def __init__(
        self, data: dict[str, Any], path: Path | None = None, base_dir: Path | None = None, *, check_files: bool = True
    ):
        self.data = data
        self.path = path
        self.base_dir = Path(base_dir if base_dir is not None else (path.parent if path else Path.cwd()))
        try:
            self.model = SceneConfig.model_validate(
                data, context={"base_dir": self.base_dir, "check_files": check_files}
            )
        except ValidationError as e:
            field, message = first_error(e, data)
            raise ConfigError(path, field, message) from None
        m = self.model
        self.seed: int = m.seed
        self.name: str = m.name or (path.stem if path else "scene")
        self.terrain: TerrainConfig = m.terrain
        self.maps: MapsConfig = m.maps
        self.scatter: ScatterConfig = m.scatter
        self.species: tuple[SpeciesConfig, ...] = tuple(m.species)
        self.ecosystem: EcosystemConfig = m.ecosystem
        self.camera: CameraConfig = m.camera
        self.lights: LightsConfig = m.lights
        self.render: RenderConfig = m.render
        self.lod: LodConfig = m.lod
        self.wind: WindConfig = m.wind
        self.lookdev: LookdevConfig = m.lookdev
        self.export: ExportConfig = m.export
        self.partitions: tuple[Partition, ...] = tuple(Partition(c, n) for c, n in m.partitions.labels)
        self.partition_tolerance: int = m.partitions.tolerance

    def fail(self, field: str, message: str) -> ConfigError:
        """A :class:`ConfigError` for ``field`` of this config (to raise)."""
        return ConfigError(self.path, field, message)

    def with_overrides(self, overrides: dict[str, Any]) -> Config:
        """A new config with dotted-key ``overrides`` applied (see :func:`apply_overrides`)."""
        return Config(apply_overrides(self.data, overrides), self.path, self.base_dir)

    def files(self) -> list[Path]:
        """Every existing file the config names (see :func:`referenced_files`)."""
        return referenced_files(self)


_KEY = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?")


def apply_overrides(data: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """A deep copy of TOML ``data`` with ``{"render.spp": 16, "species[0].percent": 40, …}`` set.

    Keys are dotted paths through tables, with ``[i]`` for an element of an
    array of tables; missing tables are created.  Nothing is validated here:
    the result goes through the schema like any file (:class:`Config`), so an
    override is held to the same rules and reported with the same field name.
    """
    out = copy.deepcopy(data)
    for dotted, value in overrides.items():
        parts = dotted.split(".")
        node: Any = out
        for i, part in enumerate(parts):
            m = _KEY.fullmatch(part)
            if m is None:
                raise ForestError(f"override {dotted!r}: {part!r} is not a key")
            key, index = m.group(1), m.group(2)
            last = i == len(parts) - 1
            if not isinstance(node, dict):
                raise ForestError(f"override {dotted!r}: {'.'.join(parts[:i])} is not a table")
            if index is None:
                if last:
                    node[key] = value
                else:
                    node = node.setdefault(key, {})
                continue
            arr = node.get(key)
            if not isinstance(arr, list) or int(index) >= len(arr):
                raise ForestError(f"override {dotted!r}: {key} has no element {index}")
            if last:
                arr[int(index)] = value
            else:
                node = arr[int(index)]
    return out


def _depth(value: Any, limit: int) -> int:
    """Nesting depth of TOML data, stopping once it exceeds ``limit``."""
    stack = [(value, 1)]
    deepest = 0
    while stack:
        v, d = stack.pop()
        deepest = max(deepest, d)
        if deepest > limit:
            return deepest
        if isinstance(v, dict):
            stack.extend((x, d + 1) for x in v.values())
        elif isinstance(v, list):
            stack.extend((x, d + 1) for x in v)
    return deepest


def read_toml(text: str, path: Path | None = None) -> dict[str, Any]:
    """Parse scene-file TOML with the size and nesting limits; one :class:`ConfigError` line otherwise."""
    if len(text.encode("utf-8", "replace")) > MAX_CONFIG_BYTES:
        raise ConfigError(path, None, f"the config is over {MAX_CONFIG_BYTES // 1024} KiB")
    text = text.removeprefix("\ufeff")  # a UTF-8 byte-order mark is no TOML statement
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, None, f"invalid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(path, None, f"invalid TOML: nested deeper than {MAX_DEPTH} levels") from None
    if _depth(data, MAX_DEPTH) > MAX_DEPTH:
        raise ConfigError(path, None, f"tables and arrays are nested deeper than {MAX_DEPTH} levels")
    return data


def load_config(path: str | Path, overrides: dict[str, Any] | None = None) -> Config:
    """Read, parse and validate a TOML scene config.  Raises :class:`ForestError` on any problem."""
    path = Path(path)
    if not path.is_file():
        if path.is_dir():
            raise ForestError(f"{path}: is a folder, not a config file")
        raise ForestError(f"{path}: {'is not a regular file' if path.exists() else 'config file not found'}")
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise ConfigError(path, None, f"the config is over {MAX_CONFIG_BYTES // 1024} KiB")
        text = path.read_text(encoding="utf-8-sig")  # a UTF-8 byte-order mark (some Windows editors) is dropped
    except (OSError, UnicodeDecodeError) as e:
        raise ForestError(f"{path}: cannot read config: {e}") from None
    return parse_config(text, path=path.resolve(), overrides=overrides)


def parse_config(
    text: str, path: Path | None = None, base_dir: Path | None = None, overrides: dict[str, Any] | None = None
) -> Config:
    """Parse and validate TOML text (e.g. received by the job service) into a :class:`Config`."""
    data = read_toml(text, path)
    if overrides:
        data = apply_overrides(data, overrides)
    return Config(data, path=path, base_dir=base_dir)


def referenced_files(config: Config) -> list[Path]:
    """Every existing file the config names — the schema's file fields and mesh species — sorted."""
    found: list[Path] = []
    for dotted in file_fields():
        found.extend(_values(config.model, dotted.replace("[]", "").split(".")))
    for sp in config.species:
        if sp.is_mesh:
            p = Path(sp.model).expanduser()
            found.append(p if p.is_absolute() else config.base_dir / p)
    return sorted({p for p in found if isinstance(p, Path) and p.is_file()})


def rebase_paths(data: dict[str, Any], base_dir: Path, out_dir: Path) -> dict[str, Any]:
    """A copy of TOML ``data`` whose relative file fields (and mesh species) are relative to ``out_dir``.

    The fields are the schema's file fields (:func:`file_fields`) and
    ``species[].model`` where it names a mesh; a config written with the result
    into ``out_dir`` names the same files as the original did from ``base_dir``.
    """
    import os

    from .schema import is_mesh_model

    out = copy.deepcopy(data)

    def rebase(value: Any) -> Any:
        if not isinstance(value, str) or not value or Path(value).expanduser().is_absolute():
            return value
        return os.path.relpath((Path(base_dir) / value).resolve(), Path(out_dir).resolve())

    for dotted in file_fields():
        _rewrite(out, dotted.split("."), rebase)
    for sp in out.get("species", []) if isinstance(out.get("species"), list) else []:
        if isinstance(sp, dict) and is_mesh_model(str(sp.get("model", ""))):
            sp["model"] = rebase(sp["model"])
    return out


def file_values(data: dict[str, Any]) -> list[tuple[str, str]]:
    """``(dotted field, string)`` of every file a config's TOML data names, for consumers of raw data.

    The schema's file fields (:func:`file_fields`, e.g. ``maps.colour``) and each
    ``species[i].model`` that names a mesh.  Values are as written (relative to
    the config's folder); nothing is validated here.
    """
    from .schema import is_mesh_model

    out: list[tuple[str, str]] = []

    def walk(node: Any, keys: list[str], where: str) -> None:
        if not keys:
            if isinstance(node, str):
                out.append((where, node))
            return
        key = keys[0]
        if key.endswith("[]"):
            items = node.get(key[:-2]) if isinstance(node, dict) else None
            for i, item in enumerate(items if isinstance(items, list) else []):
                walk(item, keys[1:], f"{where}{key[:-2]}[{i}].")
            return
        if isinstance(node, dict) and key in node:
            walk(node[key], keys[1:], f"{where}{key}" + ("." if len(keys) > 1 else ""))

    for dotted in file_fields():
        walk(data, dotted.split("."), "")
    species = data.get("species")
    for i, sp in enumerate(species if isinstance(species, list) else []):
        model = sp.get("model") if isinstance(sp, dict) else None
        if isinstance(model, str) and is_mesh_model(model):
            out.append((f"species[{i}].model", model))
    return out


def _rewrite(node: Any, keys: list[str], fn: Callable[[Any], Any]) -> None:
    key = keys[0]
    if key.endswith("[]"):
        items = node.get(key[:-2]) if isinstance(node, dict) else None
        for item in items if isinstance(items, list) else []:
            _rewrite(item, keys[1:], fn)
        return
    if not isinstance(node, dict) or key not in node:
        return
    if len(keys) == 1:
        node[key] = fn(node[key])
    else:
        _rewrite(node[key], keys[1:], fn)


def _values(node: Any, keys: list[str]) -> list[Any]:
    if not keys:
        return [node]
    if isinstance(node, list):
        return [v for item in node for v in _values(item, keys)]
    child = getattr(node, keys[0], None)
    return [] if child is None else _values(child, keys[1:])


__all__ = [
    "MAX_CONFIG_BYTES",
    "MAX_IMAGE_SIDE",
    "MAX_TREES",
    "CameraConfig",
    "CameraKey",
    "Config",
    "ConfigError",
    "EcosystemConfig",
    "ExportConfig",
    "LightsConfig",
    "LodConfig",
    "LookdevConfig",
    "MapsConfig",
    "Partition",
    "RenderConfig",
    "ScatterConfig",
    "SceneConfig",
    "SkyConfig",
    "SpeciesConfig",
    "SunConfig",
    "SunskyConfig",
    "TerrainConfig",
    "WindConfig",
    "apply_overrides",
    "file_fields",
    "file_values",
    "load_config",
    "parse_config",
    "read_toml",
    "rebase_paths",
    "referenced_files",
]
