"""The tree library: species, levels of detail and parts, read from ``manifest.toml`` files.

A library is layered: the **shipped** library (the presets installed with
forest as ``forest.library_files``; read-only) under a **user** library
(``$FOREST_LIBRARY``, else a per-user data folder such as
``~/.local/share/forest/library``) that holds imported species
(``forest library add``), species of the user's own that shadow presets of the
same name, and the build cache.  Nothing is ever written into the installed
package or the checkout.

Species are built (generated species) into ``<user library>/cache/<name>-<hash>/``
on first use, where ``hash`` covers the recipe, the seed and the generator's
code — editing a recipe or the generator therefore gives a fresh folder and a
fresh preview, and a stale folder is never read.  Building writes into a
temporary folder and renames it into place, so processes that build the same
species at once never see a half-built one.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config.schema import MESH_SUFFIXES
from ..errors import ConfigError, ForestError
from .mesh import MeshData, read_ply

MANIFEST = "manifest.toml"
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_-]{0,63}$")


class NotBuilt(ForestError):
    """A generated species asked for with ``build=False`` has no complete build of its current recipe."""


@dataclass(frozen=True)
class Part:
    """One material's mesh within a level of detail.

    ``kind`` is ``"leaf"`` (two-sided, alpha from ``texture``'s alpha channel,
    ``translucency`` share of diffuse transmission, ``sheen`` and ``roughness`` its cuticle's
    rough specular lobe), ``"bark"`` (diffuse) or
    ``"surface"`` (an imported material, diffuse).  Reflectance is
    ``colour × texture.rgb`` (texture sRGB-decoded; 1 without a texture),
    multiplied by the colour map's tint where ``tinted``.
    """

    kind: str
    path: Path
    colour: tuple[float, float, float]
    texture: Path | None
    tinted: bool
    translucency: float
    triangles: int
    bounds: np.ndarray
    sheen: float = 0.0  # leaves: weight s of the cuticle's rough specular lobe (0: Lambertian)
    roughness: float = 0.0  # its GGX α

    def load(self) -> MeshData:
        """Read the part's PLY into numpy arrays."""
        return read_ply(self.path)


@dataclass(frozen=True)
class Lod:
    """One level of detail: ``name`` in high/medium/low/far, exact object-space bounds."""

    name: str
    triangles: int
    bounds: np.ndarray  # (2, 3) float64 [min, max]
    parts: tuple[Part, ...]


@dataclass
class Species:
    """A species of the library with its levels of detail (ordered high, medium, low, far)."""

    name: str
    source: str  # "generated" | "imported"
    folder: Path
    lods: list[Lod]
    hash: str
    library: Library = field(repr=False, compare=False)
    description: str = ""

    def lod(self, name: str) -> Lod:
        """The level of detail named ``name``; ``ForestError`` when the species has none of that name."""
        for lod in self.lods:
            if lod.name == name:
                return lod
        raise ForestError(f"species {self.name!r} has no level of detail {name!r}")

    @property
    def bounds(self) -> np.ndarray:
        """Bounds of the highest level of detail."""
        return self.lods[0].bounds

    @property
    def preview_path(self) -> Path:
        """Where the preview PNG is cached: ``cache/previews/<name>-<hash prefix>.png``."""
        return self.library.cache / "previews" / f"{self.name}-{self.hash[:16]}.png"

    @property
    def preview(self) -> Path:
        """Path of the preview PNG, rendered with Mitsuba on first use (cached by the species' hash)."""
        p = self.preview_path
        if not p.is_file():
            from .preview import render_preview_file

            render_preview_file(self, p)
        return p


def _load_meta(folder: Path) -> dict | None:
    f = folder / "species.json"
    if not f.is_file():
        return None
    try:
        return json.loads(f.read_text())
    except (OSError, ValueError):
        return None


def _species_from_meta(lib: Library, meta: dict, folder: Path, description: str = "") -> Species:
    lods = []
    for L in meta["lods"]:
        parts = tuple(
            Part(
                kind=p["kind"],
                path=folder / p["file"],
                colour=tuple(p["colour"]),
                texture=(folder / p["texture"]) if p.get("texture") else None,
                tinted=bool(p["tinted"]),
                translucency=float(p["translucency"]),
                triangles=int(p["triangles"]),
                bounds=np.array(p["bounds"], dtype=np.float64),
                sheen=float(p.get("sheen", 0.0)),
                roughness=float(p.get("roughness", 0.0)),
            )
            for p in L["parts"]
        )
        lods.append(Lod(L["name"], int(L["triangles"]), np.array(L["bounds"], dtype=np.float64), parts))
    return Species(meta["name"], meta["source"], folder, lods, meta["hash"], lib, description)


def shipped_root() -> Path:
    """The folder of the library shipped with forest (manifest and recipes; read-only)."""
    from importlib.resources import files

    return Path(str(files("forest.library_files")))


def user_root() -> Path:
    """The user's library folder: ``$FOREST_LIBRARY``, else the per-user data folder."""
    env = os.environ.get("FOREST_LIBRARY")
    if env:
        return Path(env).expanduser()
    import platformdirs

    return platformdirs.user_data_path("forest") / "library"


def _read_manifest(path: Path) -> dict:
    if not path.is_file():
        return {}
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(path, None, f"cannot read: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(path, None, f"invalid TOML: {e}") from None
    sp = data.get("species", {})
    if not isinstance(sp, dict):
        raise ConfigError(path, "species", "must be a table of [species.NAME] tables")
    return sp


MANIFEST_HEADER = "forest tree library (see `forest library --help`)."


def write_manifest_entry(path: Path, name: str, entry: dict) -> None:
    """Set ``[species.NAME]`` of the manifest at ``path`` to ``entry`` and write it atomically.

    The manifest is edited as a TOML document (tomlkit), so its comments, the
    order of its tables and every other entry stay as they were; a replaced
    entry keeps its place.  Strings are escaped by the writer, so a file name
    with a backslash or a quote reads back as it was written.  A missing
    manifest is created with ``version = 1``.
    """
    import tomlkit

    from ..atomic import atomic_path

    if path.is_file():
        try:
            doc = tomlkit.parse(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError) as e:
            raise ConfigError(path, None, f"cannot read: {e}") from None
        except tomlkit.exceptions.ParseError as e:
            raise ConfigError(path, None, f"invalid TOML: {e}") from None
    else:
        doc = tomlkit.document()
        doc.add(tomlkit.comment(MANIFEST_HEADER))
        doc.add("version", 1)
    species = doc.get("species")
    if species is None:
        species = tomlkit.table(is_super_table=True)
        doc.add("species", species)
    elif not isinstance(species, dict):
        raise ConfigError(path, "species", "must be a table of [species.NAME] tables")
    table = tomlkit.table()
    for k, v in entry.items():
        table.add(k, v)
    species[name] = table  # replaced where it stands, or appended
    text = tomlkit.dumps(doc)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


class Library:
    """A writable folder (``manifest.toml``, ``presets/``, ``imported/``, ``cache/``) over
    an optional read-only ``base`` folder (the shipped presets).

    Species of ``root``'s manifest shadow those of ``base`` with the same name;
    recipe and mesh paths are relative to the folder whose manifest names them.
    """

    def __init__(self, root: Path, base: Path | None = None):
        self.root = Path(root)
        self.base = None if base is None else Path(base)
        self.manifest_path = self.root / MANIFEST
        self.cache = self.root / "cache"
        self._species: dict[str, Species] = {}

    # -- manifest -----------------------------------------------------------
    def _entries(self) -> dict[str, tuple[dict, Path]]:
        """name → (manifest entry, the folder it is relative to), user entries over shipped ones."""
        out: dict[str, tuple[dict, Path]] = {}
        for folder in (self.base, self.root):
            if folder is None:
                continue
            for name, e in _read_manifest(folder / MANIFEST).items():
                if not isinstance(e, dict):
                    raise ConfigError(folder / MANIFEST, f"species.{name}", "must be a table")
                out[name] = (e, folder)
        return out

    @property
    def manifest(self) -> dict:
        """The merged manifest: ``{"version": 1, "species": {name: entry}}``."""
        return {"version": 1, "species": {k: e for k, (e, _) in self._entries().items()}}

    def _where(self, name: str) -> tuple[dict, Path]:
        entries = self._entries()
        if name not in entries:
            raise ForestError(f"unknown species {name!r}: the library has {', '.join(sorted(entries)) or 'no species'}")
        return entries[name]

    def entry(self, name: str) -> dict:
        """The manifest table of species ``name`` (user library first, then the shipped one)."""
        return self._where(name)[0]

    def names(self) -> list[str]:
        """Species names of both layers, sorted."""
        return sorted(self._entries())

    # -- species --------------------------------------------------------------
    def recipe(self, name: str) -> tuple[dict, int]:
        """The raw recipe table and seed of a generated species."""
        e, folder = self._where(name)
        manifest = folder / MANIFEST
        field_ = f"species.{name}"
        rel = e.get("recipe")
        if not isinstance(rel, str) or not rel:
            raise ConfigError(manifest, f"{field_}.recipe", "must name a preset file")
        path = folder / rel
        if not path.is_file():
            raise ConfigError(manifest, f"{field_}.recipe", f"file not found: {rel}")
        try:
            recipe = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as e2:
            raise ConfigError(path, None, f"invalid TOML: {e2}") from None
        seed = e.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ConfigError(manifest, f"{field_}.seed", f"must be a whole number >= 0, got {seed!r}")
        return recipe, seed

    def get(self, name: str, *, seed: int | None = None, build: bool = True) -> Species:
        """The species ``name`` (built into the cache if needed); ``seed`` overrides the manifest's."""
        key = name if seed is None else f"{name}@{seed}"
        if key in self._species:
            return self._species[key]
        e, where = self._where(name)
        source = e.get("source", "generated")
        desc = str(e.get("description", ""))
        if source == "generated":
            sp = self._generated(name, seed, desc, build)
        elif source == "imported":
            if seed is not None:
                raise ForestError(f"{name}@{seed}: only generated species take a seed")
            rel = e.get("path")
            if not isinstance(rel, str):
                raise ConfigError(where / MANIFEST, f"species.{name}.path", "must name the species' folder")
            folder = where / rel
            meta = _load_meta(folder)
            if meta is None:
                raise ConfigError(
                    where / MANIFEST,
                    f"species.{name}.path",
                    f"{rel}/species.json is missing or unreadable; re-import with `forest library add`",
                )
            sp = _species_from_meta(self, meta, folder, desc)
        else:
            raise ConfigError(
                where / MANIFEST, f"species.{name}.source", f"must be generated or imported, got {source!r}"
            )
        self._species[key] = sp
        return sp

    def _generated(self, name: str, seed: int | None, desc: str, build: bool) -> Species:
        raw, manifest_seed = self.recipe(name)
        seed = manifest_seed if seed is None else seed
        e, where = self._where(name)
        kind = raw.get("kind", "tree")
        if kind == "building":  # procedural buildings (forest.library.buildings)
            from .buildings import generate, recipe_hash, validate_recipe
        elif kind == "rock":  # procedural rocks (forest.library.rocks)
            from .rocks import generate, recipe_hash, validate_recipe
        elif kind == "tree":
            from .build import generate, recipe_hash
            from .generator import validate_recipe
        else:
            raise ConfigError(where / e["recipe"], "kind", f"must be tree, building or rock, got {kind!r}")
        recipe = validate_recipe(raw, str(where / e["recipe"]))
        h = recipe_hash(recipe, seed)
        label = name if seed == manifest_seed else f"{name}@{seed}"
        folder = self.cache / f"{label}-{h[:16]}"
        meta = _load_meta(folder)
        if meta is None:
            if not build:
                raise NotBuilt(f"species {label!r} is not built; run `forest library build`")
            self.cache.mkdir(parents=True, exist_ok=True)
            tmp = Path(tempfile.mkdtemp(prefix=f".{label}.", suffix=".tmp", dir=self.cache))
            try:
                generate(raw, seed, tmp, name=label, where=str(where / e["recipe"]))
                os.chmod(tmp, 0o755)  # mkdtemp makes it private
                try:
                    os.rename(tmp, folder)
                except OSError:
                    if _load_meta(folder) is None:  # someone else won the race with a complete folder, or fail
                        raise
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
            meta = _load_meta(folder)
            if meta is None:
                raise ForestError(f"library: {folder} has no complete species metadata after building {label}")
        return _species_from_meta(self, meta, folder, desc)

    def is_fresh(self, name: str) -> bool:
        """True when ``name``'s cached files match its recipe (or it is imported and complete)."""
        try:
            self.get(name, build=False)
            return True
        except ForestError:
            return False

    def resolve(self, model: str, base_dir: str | Path | None = None) -> Species:
        """A species for a scene's ``model``: a library name, ``NAME@SEED``, or a mesh file path.

        Mesh paths are relative to ``base_dir`` (a config's folder) and are
        imported into the cache on first use (keyed by the file's content).
        """
        if not isinstance(model, str) or not model:
            raise ForestError(f"species model must be a non-empty string, got {model!r}")
        names = set(self.names())
        if model in names:
            return self.get(model)
        m = re.fullmatch(r"(.+)@(\d+)", model)
        if m and m.group(1) in names:
            return self.get(m.group(1), seed=int(m.group(2)))
        p = Path(model).expanduser()
        if p.suffix.lower() in MESH_SUFFIXES:
            if not p.is_absolute() and base_dir is not None:
                p = Path(base_dir) / p
            from .importer import import_cached

            return import_cached(self, p)
        raise ForestError(
            f"unknown species {model!r}: not in the library "
            f"({', '.join(sorted(names)) or 'empty'}) and not a mesh file "
            f"({', '.join(MESH_SUFFIXES)})"
        )

    def species(self) -> list[Species]:
        """Every species of both layers by :meth:`get` (built if stale), in :meth:`names` order."""
        return [self.get(n) for n in self.names()]

    def build(
        self, names: list[str] | None = None, *, previews: bool = True, progress=None, prune: bool = False
    ) -> list[Species]:
        """Build (if stale) every species in ``names`` (all by default) and their previews.

        With ``prune`` (off by default: the cache is shared by every forest install
        and version of a user), cache folders of generated species that no longer match
        any recipe are removed.
        """
        names = self.names() if names is None else names
        out = []
        for i, n in enumerate(names):
            if progress:
                progress(i / max(len(names), 1), n)
            sp = self.get(n)
            if previews:
                sp.preview  # noqa: B018 - renders when missing
            out.append(sp)
        if prune and names == self.names():
            self.prune({sp.folder.name for sp in out}, {sp.preview_path.name for sp in out})
        if progress:
            progress(1.0, "done")
        return out

    def prune(self, keep_dirs: set[str], keep_previews: set[str], *, stale_tmp_s: float = 600.0) -> None:
        """Remove cache folders and previews not in the keep sets (and temporary folders
        left over ten minutes ago by interrupted builds)."""
        if not self.cache.is_dir():
            return
        import time

        now = time.time()
        for p in self.cache.glob(".*.tmp"):
            try:
                if p.is_dir() and now - p.stat().st_mtime > stale_tmp_s:
                    shutil.rmtree(p, ignore_errors=True)
            except OSError:
                pass
        for p in self.cache.iterdir():
            if p.is_dir() and p.name in keep_dirs and (p.stat().st_mode & 0o777) != 0o755:
                os.chmod(p, 0o755)
            if (
                p.is_dir()
                and p.name not in ("previews", "imported")
                and not p.name.startswith(".")
                and p.name not in keep_dirs
                and "@" not in p.name
            ):
                shutil.rmtree(p, ignore_errors=True)
        pv = self.cache / "previews"
        if pv.is_dir():
            for p in pv.iterdir():
                if p.suffix == ".png" and p.name not in keep_previews and "@" not in p.name:
                    p.unlink(missing_ok=True)


def open_library(root: str | Path | None = None, *, presets: bool = True) -> Library:
    """The tree library: the user library at ``root`` (default :func:`user_root`) layered
    over the shipped presets (``presets=False``: ``root`` alone).

    Opening the shipped folder itself gives it alone, with its cache beside it
    (a checkout's ``library/``).
    """
    root = user_root() if root is None else Path(root).expanduser()
    if root.exists() and not root.is_dir():
        raise ForestError(f"{root}: the tree library must be a folder")
    shipped = shipped_root()
    same = root.exists() and shipped.exists() and root.resolve() == shipped.resolve()
    return Library(root, base=shipped if presets and not same else None)
