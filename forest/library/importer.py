"""Importing meshes as species: OBJ (with MTL materials), PLY, glTF/GLB, STL — anything trimesh reads.

Steps, for a file and a name:

1. **Check** the file (exists, non-empty, at most :data:`MAX_FILE_BYTES`), load it
   with trimesh as a scene and reject, with one line naming the file, scenes with
   no triangles (empty files, point clouds, line drawings), non-finite vertices
   or more than :data:`MAX_TRIANGLES` triangles.
2. **Flatten** the scene graph (each node's transform applied) and group the
   triangles by material into parts.  Material colours (OBJ ``Kd``, glTF
   ``baseColorFactor``) are linear; textures are sRGB images kept as PNG.
   Parts whose geometry or material name says leaf/foliage/needle/frond/canopy,
   or whose texture is an alpha cut-out (over 5 % of texels below ½ alpha),
   become ``leaf`` parts (two-sided, alpha-tested) and are tinted by the colour
   map; if no name says so, the greenest part (``g > r`` and ``g > b``) is
   tinted, and failing that every part.  An untinted part named bark, trunk,
   branch, twig, stem or wood becomes ``bark``: each tree's bark factor
   (``[[species]] bark``: jitter and moss) multiplies it.
3. **Normalise**: rotate a Z-up file to Y up (``(x, y, z) → (x, z, −y)``), scale
   to metres (``--units`` or the file's own unit, or ``--height``), then translate
   so the base sits at the origin: ``y_min = 0`` and the X/Z bounding-box centre
   at ``(0, 0)``.
4. **Levels of detail**: high is the mesh itself (decimated to 200 000 triangles
   when larger); medium and low get about 12 000 and 1 500 triangles, shared
   among the parts by their triangle counts — leaf parts made of many small
   cards keep a random subset of whole cards, enlarged to keep their total area
   (:func:`forest.library.mesh.thin_cards`; other leaf meshes are vertex-clustered,
   :func:`forest.library.mesh.decimate_to`), solid parts are simplified by quadric
   error (Garland & Heckbert 1997, :func:`forest.library.mesh.quadric_decimate`),
   which keeps trunk and branch silhouettes, UVs carried over from the nearest
   source triangle; far is the crossed-card impostor
   (:func:`forest.library.lod.impostor`).
5. **Store** the parts as PLY under ``imported/NAME/`` with ``species.json``,
   add ``[species.NAME]`` to the manifest, and render the preview.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ForestError, ParameterError
from ..images import srgb_to_linear
from . import lod as lodmod
from .build import code_hash, far_coverage, lod_entry, part_entry, write_json
from .core import MESH_SUFFIXES, NAME_RE, Library, Species, _load_meta, _species_from_meta, write_manifest_entry
from .mesh import MeshData, decimate_to, quadric_decimate, thin_cards, vertex_normals, write_ply
from .textures import write_texture

MAX_FILE_BYTES = 256 * 1024 * 1024
MAX_TRIANGLES = 5_000_000
HIGH_MAX = lodmod.BUDGETS["high"][1]
LEAF_RE = re.compile(r"leaf|leaves|foliage|needle|frond|canopy|crown|blatt|feuill", re.I)
#: Names of the untinted parts that become ``bark`` (multiplied by each tree's bark factor, ``[[species]] bark``).
BARK_RE = re.compile(r"bark|trunk|branch|twig|stem|wood|rinde|stamm|tronc|ecorce|écorce", re.I)
UNITS = {
    "m": 1.0,
    "meters": 1.0,
    "metres": 1.0,
    "meter": 1.0,
    "cm": 0.01,
    "centimeters": 0.01,
    "mm": 0.001,
    "millimeters": 0.001,
    "in": 0.0254,
    "inches": 0.0254,
    "ft": 0.3048,
    "feet": 0.3048,
}
TAG_IMPORT = 0x1A7
#: A mesh whose total area is below this fraction of its extent squared is degenerate (points, lines, slivers).
MIN_AREA_FRACTION = 1e-9


class _Part:
    def __init__(self, key: str, label: str, colour, image):
        self.key, self.label, self.colour, self.image = key, label, colour, image
        self.vertices: list[np.ndarray] = []
        self.faces: list[np.ndarray] = []
        self.uv: list[np.ndarray] = []


def _material(geom) -> tuple[str, tuple[float, float, float], np.ndarray | None]:
    """(material name, linear RGB colour, sRGB-decoded RGBA float image or None) of a trimesh geometry."""
    vis = geom.visual
    name, colour, image = "", (0.5, 0.5, 0.5), None
    mat = getattr(vis, "material", None)
    if mat is not None:
        name = str(getattr(mat, "name", "") or "")
        factor = getattr(mat, "baseColorFactor", None)
        if factor is None:
            factor = getattr(mat, "diffuse", None)
        if factor is not None:
            f = np.asarray(factor, dtype=np.float64)[:3]
            colour = tuple(
                (f / 255.0 if f.max() > 1.0 or np.issubdtype(np.asarray(factor).dtype, np.integer) else f).tolist()
            )
        img = getattr(mat, "baseColorTexture", None)
        if img is None:
            img = getattr(mat, "image", None)
        if img is not None:
            arr = np.asarray(img.convert("RGBA"), dtype=np.float32) / 255.0
            arr[..., :3] = srgb_to_linear(arr[..., :3])
            image = arr
            if factor is None:  # the texture alone carries the colour
                colour = (1.0, 1.0, 1.0)
    elif getattr(vis, "kind", None) in ("face", "vertex"):
        c = np.asarray(vis.face_colors if vis.kind == "face" else vis.vertex_colors, dtype=np.float64)
        if len(c):
            colour = tuple(srgb_to_linear(c[:, :3].mean(axis=0) / 255.0).tolist())
    r, g, b = (float(x) for x in colour)
    return name, (r, g, b), image


def _size(n: int) -> str:
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


#: Largest vertex coordinate accepted, in the file's own unit: a tree of a billion millimetres is 1 000 km; beyond
#: that a file is broken, and its numbers would overflow the normalisation (1e308 did, with an internal error).
MAX_COORDINATE = 1e9

#: MTL statements that name a texture file (the file name is the statement's last word).
MTL_MAPS = ("map_Kd", "map_Ka", "map_Ks", "map_d", "map_Bump", "map_bump", "bump", "norm", "disp")


def missing_references(path: Path) -> list[str]:
    """What an OBJ names and the import cannot find: its material libraries (``mtllib``) and their textures.

    trimesh imports such a file without complaint, with default grey materials or no texture, so
    the import would look successful; these are said instead, one line each, naming the file.
    Other formats carry their materials inside (glTF/GLB) or have none (PLY, STL): nothing to check.
    """
    path = Path(path)
    if path.suffix.lower() != ".obj":
        return []
    out: list[str] = []
    try:
        lines = path.read_text(errors="replace").splitlines()
    except OSError:
        return []
    for line in lines:
        words = line.split(maxsplit=1)
        if len(words) < 2 or words[0] != "mtllib":
            continue
        mtl = path.parent / words[1].strip()
        if not mtl.is_file():
            out.append(f"{path.name}: material library {words[1].strip()!r} not found: imported without its materials")
            continue
        for m in mtl.read_text(errors="replace").splitlines():
            w = m.split()
            if len(w) >= 2 and w[0] in MTL_MAPS and not (mtl.parent / w[-1]).is_file():
                out.append(f"{mtl.name}: texture {w[-1]!r} ({w[0]}) not found: imported without it")
    return out


def load_parts(path: Path, *, up: str = "auto", units: str = "auto", height: float | None = None):
    """Load, check and normalise a mesh file; return ``[(label, MeshData, colour, image)]``."""
    path = Path(path)
    if not path.is_file():
        raise ForestError(f"{path}: mesh file not found")
    size = path.stat().st_size
    if size == 0:
        raise ForestError(f"{path}: mesh file is empty")
    if size > MAX_FILE_BYTES:
        raise ForestError(f"{path}: mesh file is {_size(size)}, over the {_size(MAX_FILE_BYTES)} import limit")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ForestError(f"{path}: unsupported mesh format {path.suffix or '(none)'}; use {', '.join(MESH_SUFFIXES)}")
    if up not in ("auto", "y", "z"):
        raise ParameterError("up", f"must be auto, y or z; got {up!r}")
    if units != "auto" and units not in UNITS:
        raise ParameterError("units", f"must be auto or one of {', '.join(sorted(UNITS))}; got {units!r}")
    import trimesh

    try:
        scene: Any = trimesh.load(str(path), force="scene", process=False)
    except Exception as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ForestError(f"{path}: cannot read mesh: {msg}") from None
    parts: dict[str, _Part] = {}
    total = 0
    non_tri = 0
    for node in scene.graph.nodes_geometry:
        transform, gname = scene.graph[node]
        geom = scene.geometry[gname]
        if not isinstance(geom, trimesh.Trimesh):
            non_tri += 1
            continue
        faces = np.asarray(geom.faces)
        if faces.ndim != 2 or faces.shape[1] != 3:
            non_tri += 1
            continue
        if len(faces) == 0:
            continue
        v = np.asarray(geom.vertices, dtype=np.float64)
        if not np.isfinite(v).all():
            raise ForestError(f"{path}: mesh {gname!r} has NaN or infinite vertex coordinates")
        if len(v) and np.abs(v).max() > MAX_COORDINATE:
            raise ForestError(
                f"{path}: mesh {gname!r} has vertex coordinates up to {np.abs(v).max():.3g}, beyond ±{MAX_COORDINATE:g} "
                "(a tree, in any unit)"
            )
        total += len(faces)
        if total > MAX_TRIANGLES:
            raise ForestError(f"{path}: mesh has more than {MAX_TRIANGLES:,} triangles (the import limit)")
        v = v @ np.asarray(transform)[:3, :3].T + np.asarray(transform)[:3, 3]
        mname, colour, image = _material(geom)
        uv = getattr(geom.visual, "uv", None)
        uv = np.zeros((len(v), 2)) if uv is None or len(uv) != len(v) else np.asarray(uv, dtype=np.float64)
        uv = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)  # trimesh gives v up; Mitsuba reads v down
        key = f"{mname}|{colour}|{id(image) if image is not None else ''}"
        label = f"{gname} {mname}".strip()
        if key not in parts:
            parts[key] = _Part(key, label, colour, image)
        p = parts[key]
        off = sum(len(x) for x in p.vertices)
        p.vertices.append(v)
        p.faces.append(faces.astype(np.int64) + off)
        p.uv.append(uv)
    if total == 0:
        what = "only points or lines, no triangles" if non_tri else "no triangles"
        raise ForestError(f"{path}: mesh is empty ({what})")
    # Normalise: up axis, units, base at the origin.
    if up == "auto":
        up = "z" if path.suffix.lower() == ".stl" else "y"
    scale = 1.0
    if units != "auto":
        scale = UNITS[units]
    elif getattr(scene, "units", None) and str(scene.units).lower() in UNITS:
        scale = UNITS[str(scene.units).lower()]
    allv = np.concatenate([np.concatenate(p.vertices) for p in parts.values()])
    if up == "z":
        allv = np.stack([allv[:, 0], allv[:, 2], -allv[:, 1]], axis=1)
    allv = allv * scale
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    if height is not None:
        if hi[1] - lo[1] <= 0:
            raise ForestError(f"{path}: --height: the mesh is flat, cannot scale it to a height")
        allv = allv * (height / (hi[1] - lo[1]))
        lo, hi = allv.min(axis=0), allv.max(axis=0)
    if not np.isfinite(allv).all() or float(np.max(hi - lo)) <= 0:
        raise ForestError(f"{path}: mesh has degenerate extent {(hi - lo).tolist()}")
    area = _surface_area(allv, np.concatenate([np.concatenate(p.faces) for p in parts.values()]))
    if not area > MIN_AREA_FRACTION * float(np.max(hi - lo)) ** 2:
        raise ForestError(
            f"{path}: mesh has no surface area ({area:.3g} m² over a {float(np.max(hi - lo)):.3g} m extent): "
            "every triangle is degenerate"
        )
    allv = allv - np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    out = []
    start = 0
    for p in parts.values():
        n = sum(len(x) for x in p.vertices)
        v = allv[start : start + n]
        start += n
        f = np.concatenate(p.faces)
        uv = np.concatenate(p.uv)
        mesh = MeshData(v.astype(np.float32), f.astype(np.uint32), vertex_normals(v, f), uv.astype(np.float32))
        out.append((p.label, mesh, p.colour, p.image))
    return out


def _surface_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total area Σ ½‖(b − a) × (c − a)‖ of the triangles ``faces`` over ``vertices`` (float64)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())


def _classify(parts) -> list[tuple[str, bool]]:
    """(kind, tinted) per part: leaf by name; tint leaves, else the greenest part, else all; an untinted part named
    bark, trunk, branch … is ``bark``."""
    kinds = []
    for label, _mesh, _colour, image in parts:
        # Leaves by name, or by an alpha-cut texture (cards whose texels are partly transparent).
        cutout = image is not None and image.shape[2] == 4 and float((image[..., 3] < 0.5).mean()) > 0.05
        leafy = bool(LEAF_RE.search(label)) or cutout
        kinds.append("leaf" if leafy else "surface")
    if "leaf" in kinds:
        tinted = [k == "leaf" for k in kinds]
    else:
        green = [c[1] > c[0] and c[1] > c[2] for _, _, c, _ in parts]
        tinted = green if any(green) else [True] * len(kinds)
    return [
        ("bark" if k == "surface" and not t and BARK_RE.search(label) else k, t)
        for (label, *_), k, t in zip(parts, kinds, tinted)
    ]


def seed_of(digest: str) -> int:
    """A generation seed from a mesh digest: its first 32 bits (0 without a digest)."""
    return int(digest[:8], 16) if digest else 0


def convert(
    path: Path,
    out: Path,
    name: str,
    *,
    up: str = "auto",
    units: str = "auto",
    height: float | None = None,
    digest: str = "",
) -> dict:
    """Import ``path`` into folder ``out`` (PLY per part per level, textures, species.json)."""
    parts = load_parts(path, up=up, units=units, height=height)
    classes = _classify(parts)
    out.mkdir(parents=True, exist_ok=True)
    textures: list[str | None] = []
    for i, (_label, _mesh, _colour, image) in enumerate(parts):
        if image is not None:
            write_texture(out / f"texture{i}.png", image)
            textures.append(f"texture{i}.png")
        else:
            textures.append(None)
    total = sum(m.triangles for _, m, _, _ in parts)
    lods = []
    high_meshes = []
    for lod in ("high", "medium", "low"):
        target = HIGH_MAX if lod == "high" else lodmod.TARGETS[lod]
        entries = []
        for i, ((_label, mesh, colour, image), (kind, tinted)) in enumerate(zip(parts, classes)):
            share = max(8, int(round(target * mesh.triangles / total)))
            m = mesh
            if mesh.triangles > share:
                # Leaf cards thin out as whole cards (area kept), other leaf meshes cluster (their alpha cut-outs
                # hang on UVs); solid surfaces (trunks, branches) collapse edges by quadric error.
                if kind == "leaf":
                    thinned = thin_cards(mesh, share, seed_of(digest), TAG_IMPORT + i)
                    m = thinned if thinned is not None and thinned.triangles else decimate_to(mesh, share)
                else:
                    m = quadric_decimate(mesh, share)
            if m.triangles == 0:
                continue
            fname = f"{lod}_part{i}.ply"
            write_ply(out / fname, m)
            entries.append(part_entry(kind, fname, m, colour, textures[i], tinted, 0.3 if kind == "leaf" else 0.0))
            if lod == "high":
                high_meshes.append((m, np.asarray(colour), image))
        lods.append(lod_entry(lod, entries))
    bounds = np.array(lods[0]["bounds"])
    seed = seed_of(digest)
    coverage = far_coverage(out, lods[0], bounds)
    far, atlas, scale = lodmod.impostor(high_meshes, bounds, seed=seed, coverage=coverage)
    write_texture(out / "far.png", atlas)
    write_ply(out / "far_cards.ply", far)
    any_tint = any(t for _, t in classes)
    lods.append(lod_entry("far", [part_entry("leaf", "far_cards.ply", far, scale, "far.png", any_tint, 0.2)]))
    meta = {
        "name": name,
        "source": "imported",
        "original": path.name,
        "hash": digest,
        "lods": lods,
        "options": {"up": up, "units": units, "height": height},
    }
    write_json(out / "species.json", meta)
    return meta


def _digest(path: Path, **options) -> str:
    h = hashlib.sha256()
    h.update(code_hash().encode())
    h.update(repr(sorted(options.items())).encode())
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _into_place(path: Path, folder: Path, name: str, replace: bool, **options) -> dict:
    """Convert into a temporary folder beside ``folder`` and rename it into place."""
    if not path.is_file():
        raise ForestError(f"{path}: mesh file not found")
    created = _make_dirs(folder.parent)
    done = False
    try:
        digest = _digest(path, **options)
        tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
        old = None
        try:
            meta = convert(path, tmp, name, digest=digest, **options)
            os.chmod(tmp, 0o755)  # mkdtemp makes it private
            if folder.exists():
                if not replace:
                    done = True
                    return _load_meta(folder) or meta
                old = folder.with_name(f".{folder.name}.old{os.getpid()}")
                os.rename(folder, old)
            os.rename(tmp, folder)
            done = True
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
    finally:
        if not done:  # a failed import leaves no empty folder behind (``imported/``, the library itself)
            for d in reversed(created):
                with contextlib.suppress(OSError):
                    d.rmdir()
    return meta


def _make_dirs(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; return the folders created, outermost first."""
    missing = []
    p = folder
    while not p.exists():
        missing.append(p)
        if p.parent == p:
            break
        p = p.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ForestError(f"{folder}: cannot create the library folder: {e.strerror or e}") from None
    return list(reversed(missing))


def import_cached(lib: Library, path: Path) -> Species:
    """A mesh path used directly as a scene's ``model``: imported into ``cache/imported/`` once."""
    path = Path(path)
    if not path.is_file():
        raise ForestError(f"{path}: mesh file not found")
    digest = _digest(path, up="auto", units="auto", height=None)
    folder = lib.cache / "imported" / f"{path.stem}-{digest[:16]}"
    meta = _load_meta(folder)
    if meta is None:
        meta = _into_place(path, folder, path.stem, False, up="auto", units="auto", height=None)
    return _species_from_meta(lib, meta, folder, f"imported from {path.name}")


def add_species(
    lib: Library,
    path: str | Path,
    name: str,
    *,
    up: str = "auto",
    units: str = "auto",
    height: float | None = None,
    force: bool = False,
    preview: bool = True,
) -> Species:
    """Import ``path`` as species ``name`` into ``lib`` (files under ``imported/NAME/``, a manifest entry)."""
    path = Path(path)
    if not NAME_RE.match(name or ""):
        raise ParameterError(
            "name", f"{name!r} is not a valid species name (letters, digits, _ and -, starting with a letter)"
        )
    if name in lib.names() and not force:
        raise ParameterError(
            "name",
            f"species {name!r} already exists in the library; replace it with force "
            f"(a preset of that name is shadowed, not changed)",
        )
    if height is not None and not (math.isfinite(height) and height > 0):
        raise ParameterError("height", f"must be a positive number of metres, got {height!r}")
    folder = lib.root / "imported" / name
    meta = _into_place(path, folder, name, True, up=up, units=units, height=height)
    entry: dict[str, Any] = {"source": "imported", "path": f"imported/{name}", "original": path.name}
    entry.update((k, v) for k, v in (("up", up), ("units", units)) if v != "auto")
    if height is not None:
        entry["height"] = float(height)
    desc = f"imported from {path.name}"
    entry["description"] = desc
    write_manifest_entry(lib.manifest_path, name, entry)
    lib._species.pop(name, None)
    sp = _species_from_meta(lib, meta, folder, desc)
    if preview:
        sp.preview  # noqa: B018 - renders when missing
    return sp
