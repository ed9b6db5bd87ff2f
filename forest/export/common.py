"""What the RIB and USD exporters share: frames, species and their levels of detail.

Conventions (both exporters, and the same as the Mitsuba renderer):

* World space is the scene's: metres, **Y up, right-handed**; trees stand on
  the terrain with their base at the object origin.
* **Sun and sky** are :mod:`forest.lights`' (one rule for every backend): the
  unit vector from the ground *towards* the sun is d = (cos θ · sin φ, sin θ,
  cos θ · cos φ) for an elevation θ and an azimuth φ clockwise from +Z (north)
  towards +X (east), so φ = 0 puts the sun over +Z, φ = 90° over +X; sunlight
  travels along −d.  A physical sun-sky is written as its sun (a distant light)
  and a dome (:meth:`forest.lights.Sky.dome`).
* **Levels of detail.**  :mod:`forest.lod`'s rule: boundaries d₁ < … < dₙ
  split the distance from the camera into n + 1 bands; band i (0 = nearest)
  uses the species' i-th level (high, medium, low, far).  A species with fewer
  levels keeps its last level for the remaining bands.  The boundaries are
  ``[lod] distances``, the same for every species, or — the automatic rule,
  the default — per species from ``[lod] pixels`` (dᵢ = H·f/tᵢ for a tree of
  scale 1, H its highest level's bound height, f the camera's focal length
  in pixels); with ``[lod] auto = false`` every tree uses the first level.
* **Bark.**  A tree's bark factor f_i (:func:`bark_factors`, an RGB
  multiplier: ``[[species]] bark``'s hue/value jitter and moss) travels with
  the tree as its leaf colour does, and multiplies the colour (× texture) of
  the parts of kind ``bark`` (:func:`is_bark`); nothing of it is written when
  every f_i is 1.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..config import Config
from ..errors import ForestError, ParameterError
from ..frames import parse_frames
from ..instances import InstanceSet
from ..library import Species
from ..scatter.models import scatter_models


def export_frames(config: Config, frames: str | list[int] | None = None) -> list[int]:
    """The frames to export: ``frames`` (a spec such as ``"1-120"`` or a list), else the
    whole keyed range of the camera (first to last key, whole frames), else frame 1."""
    if frames is not None:
        out = parse_frames(frames) if isinstance(frames, str) else sorted({int(f) for f in frames})
        if not out:
            raise ParameterError("frames", "no frames selected")
        return out
    keys = config.camera.keys
    if keys:
        a, b = math.ceil(keys[0].frame), math.floor(keys[-1].frame)
        return list(range(a, b + 1)) if b >= a else [int(round(keys[0].frame))]
    return [1]


def slug(name: str) -> str:
    """A file-name-safe form of a species or partition name (a path gives its stem)."""
    s = str(name)
    if "/" in s or "\\" in s or re.search(r"\.(ply|obj|glb|gltf|stl|off)$", s, re.I):
        s = Path(s.replace("\\", "/")).stem
    s = re.sub(r"[^A-Za-z0-9_-]+", "_", s).strip("_")
    return s or "species"


def export_options(config: Config) -> dict:
    """The ``[export]`` section:

    * ``lod_transition`` — fraction of a LOD distance over which RIB levels
      cross-fade (default 0.1);
    * ``rib_lod`` — where RIB's ``Detail``/``DetailRange`` go: ``"inline"``
      (default: in every tree's block of the instance files) or ``"archive"``
      (once per species in ``archives/<species>_lod.rib``, which each tree
      reads — the same switch in the tree's object space, instance files a third
      the size);
    * ``usd_lod`` — the ``lod`` variant the USD prototypes select (default each
      species' first level).
    """
    e = config.export
    return {"lod_transition": e.lod_transition, "rib_lod": e.rib_lod, "usd_lod": e.usd_lod}


@dataclass
class Band:
    """One level of detail used for a band of camera distances [near, far) metres."""

    lod: Any  # a forest.library Lod
    near: float
    far: float  # math.inf for the last band


@dataclass
class SpeciesPlan:
    """A species of the InstanceSet as the exporters write it."""

    index: int  # index into InstanceSet.species_names
    model: str  # the config's ``model`` string
    name: str  # unique file-safe name
    species: Species  # the library species
    bands: list[Band] = field(default_factory=list)

    @property
    def lods(self) -> list:
        """The distinct levels used, in band order."""
        out: list = []
        for b in self.bands:
            if all(b.lod is not o for o in out):
                out.append(b.lod)
        return out


def species_plans(scene, *, used_only: bool = True, fov: float | None = None) -> list[SpeciesPlan]:
    """Every species of the scene with trees (all with ``used_only=False``) and its LOD bands.

    Species come resolved from the Scene; the bands from its LOD plan
    (:meth:`forest.lod.LodPlan.bands`), the one rule every backend shares,
    for a camera of horizontal field of view ``fov`` (default the config's).
    """
    instances = scene.instances
    counts = np.bincount(instances.species, minlength=len(instances.species_names))
    plans: list[SpeciesPlan] = []
    taken: set[str] = set()
    for i, model in enumerate(instances.species_names):
        if used_only and counts[i] == 0:
            continue
        sp = scene.species[i]
        name = slug(getattr(sp, "name", model))
        base, n = name, 2
        while name in taken:
            name, n = f"{base}_{n}", n + 1
        taken.add(name)
        bands = [Band(sp.lods[b.level], b.near, b.far) for b in scene.lod.bands(i, fov)]
        plans.append(SpeciesPlan(i, model, name, sp, bands))
    return plans


def wound_with_normals(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``faces`` with every triangle wound counter-clockwise about its stored normals.

    A triangle (a, b, c) faces n_g = (b − a) × (c − a); where n_g points away
    from the mean of its three stored vertex normals (n_g · n̄ < 0) the
    triangle is rewound (a, c, b).  Renderers that take a polygon's front from
    its winding (Cycles, USD consumers, RenderMan's ``Orientation``) then agree
    with the shading normals, as Mitsuba does regardless.  Triangles that
    already agree, or have no usable normal, are kept as they are, so meshes
    wound correctly come back unchanged.
    """
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or normals is None or len(normals) != len(vertices):
        return f
    v = np.asarray(vertices, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    ng = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    nbar = n[f[:, 0]] + n[f[:, 1]] + n[f[:, 2]]
    flip = np.einsum("ij,ij->i", ng, nbar) < 0
    if not flip.any():
        return f
    out = f.copy()
    out[flip, 1], out[flip, 2] = f[flip, 2], f[flip, 1]
    return out


def lod_mesh(lod):
    """All parts of one level as ``[(part, MeshData)]``, indices checked and triangles wound with
    their normals (:func:`wound_with_normals`)."""
    out = []
    for part in lod.parts:
        m = part.load()
        v = np.asarray(m.vertices, dtype=np.float32)
        f = np.asarray(m.faces, dtype=np.int64)
        if len(f) and (f.min() < 0 or f.max() >= len(v)):
            raise ForestError(f"{part.path}: face indices out of range")
        wound = wound_with_normals(v, f, m.normals)
        if wound is not f:
            m = dataclasses.replace(m, faces=wound.astype(np.asarray(m.faces).dtype))
        out.append((part, m))
    return out


def remove_stale(out_dir: Path, fresh: Path, owned: tuple[str, ...]) -> list[Path]:
    """Delete the files of an earlier export in ``out_dir`` that this export (in ``fresh``) does not write.

    Only paths matching ``owned`` (glob patterns of files, or folders the
    exporter owns entirely) are touched, so a user's own files — renders,
    notes — stay.  Returns the paths removed.
    """
    removed: list[Path] = []
    if not out_dir.is_dir():
        return removed
    for pattern in owned:
        for p in sorted(out_dir.glob(pattern)):
            files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
            for q in files:
                if not (fresh / q.relative_to(out_dir)).exists():
                    q.unlink()
                    removed.append(q)
            if p.is_dir():
                for d in sorted((d for d in p.rglob("*") if d.is_dir()), reverse=True):
                    if not any(d.iterdir()):
                        d.rmdir()
                if not any(p.iterdir()):
                    p.rmdir()
    return removed


def measured_bounds(lod, meshes=None) -> np.ndarray:
    """The level's object-space bound ``(2, 3)`` [min, max]: the library's measured
    ``lod.bounds`` grown, if need be, to contain every vertex actually written."""
    b = np.array(lod.bounds, dtype=np.float64).reshape(2, 3)
    if meshes:
        pts = [
            np.asarray(m.vertices, dtype=np.float64)[np.unique(np.asarray(m.faces).ravel())]
            for _, m in meshes
            if len(m.faces)
        ]
        if pts:
            p = np.concatenate(pts)
            b = np.stack([np.minimum(b[0], p.min(axis=0)), np.maximum(b[1], p.max(axis=0))])
    return b


def check_instances(config: Config, instances: InstanceSet) -> None:
    """The InstanceSet belongs to this config and holds finite numbers (one line otherwise)."""
    models = scatter_models(config)
    if list(instances.species_names) != models:
        raise ForestError(
            f"instances: species {instances.species_names} do not match the config's "
            f"[[species]] and [[ground_cover]] models {models}; scatter again"
        )
    for col in ("position", "rotation", "scale", "tint"):
        a = getattr(instances, col)
        if a.size and not np.isfinite(a).all():
            raise ForestError(f"instances: column {col!r} holds NaN or infinite values")
    if len(instances) and (instances.scale <= 0).any():
        raise ForestError("instances: column 'scale' must be positive")
    if len(instances.species) and int(instances.species.max()) >= len(instances.species_names):
        raise ForestError("instances: a species index is out of range of species_names")


def partition_rows(instances: InstanceSet) -> list[tuple[int, str, np.ndarray]]:
    """``(index, name, rows)`` for every partition that holds trees; rows in id order."""
    part = instances.partition.astype(np.int64)
    out: list[tuple[int, str, np.ndarray]] = []
    if len(part) == 0:
        return out
    order = np.argsort(part, kind="stable")
    counts = np.bincount(part, minlength=len(instances.partition_names))
    starts = np.concatenate([[0], np.cumsum(counts)])
    for p, name in enumerate(instances.partition_names):
        if counts[p]:
            out.append((p, name, order[starts[p] : starts[p + 1]]))
    if part.max() >= len(instances.partition_names) or part.min() < 0:
        raise ForestError("instances: partition index out of range of partition_names")
    return out


def texture_mean_detail(path) -> np.ndarray:
    """Mean linear RGB detail of a part texture over its opaque texels (alpha ≥ ½), as
    :mod:`forest.render.materials` averages it for ``scalar_rgb``."""
    from ..images import read_image, srgb_to_linear

    img = read_image(path, what="texture", unassociated=True)
    c = img.shape[2]
    rgb = img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2)
    rgb = srgb_to_linear(rgb) if Path(path).suffix.lower() not in (".exr", ".hdr") else rgb
    alpha = img[..., 3] if c == 4 else (img[..., 1] if c == 2 else None)
    mask = alpha >= 0.5 if alpha is not None else np.ones(rgb.shape[:2], bool)
    return (rgb[mask] if mask.any() else rgb.reshape(-1, 3)).mean(axis=0).astype(np.float32)


def part_albedo(part) -> np.ndarray:
    """A part's albedo before any per-tree factor, as one colour: base colour × mean texture detail."""
    c = np.asarray(part.colour, np.float32)
    tex = getattr(part, "texture", None)
    return c * texture_mean_detail(tex) if tex else c


def canopy_colour(lod) -> np.ndarray | None:
    """The colour of a level's first tinted part before the tint: base colour × mean texture detail.

    The per-tree display colour of viewers and of materials that cannot multiply
    a texture by a per-tree colour (UsdPreviewSurface) is tint × this.  None when
    no part is tinted.
    """
    for part in lod.parts:
        if getattr(part, "tinted", False):
            return part_albedo(part)
    return None


def is_bark(part) -> bool:
    """Whether a library part is bark: the parts a tree's bark factor multiplies."""
    return getattr(part, "kind", "") == "bark"


def leaf_cuticle(part) -> tuple[float, float]:
    """(s, α) of a library part's leaf cuticle lobe: its sheen weight and GGX roughness, as forest_path reads
    them (:func:`forest.render.path.materials.leaf_sheen`); (0, 0) for parts that are not leaves or have none.

    The lobe is a rough dielectric of F₀ = 0.04 (n = 1.5) over the leaf's diffuse reflection and transmission,
    which it takes its energy from (docs/rendering.md, "Leaf sheen").
    """
    if getattr(part, "kind", "") != "leaf":
        return 0.0, 0.0
    from ..render.path.materials import leaf_sheen

    return leaf_sheen(part)


#: Values of μ = |cos θ| at which :func:`cuticle_fresnel` tabulates the lobe's mean Fresnel reflectance.
CUTICLE_TABLE_SIZE = 17


@functools.lru_cache(maxsize=32)
def cuticle_fresnel(alpha: float, n: int = CUTICLE_TABLE_SIZE) -> tuple[float, ...]:
    """The cuticle lobe's mean Fresnel reflectance F̄(μ) = E(μ) / E₁(μ) at μ = k/(n − 1), k = 0 … n − 1.

    E is forest_path's lobe albedo (Fresnel at each microfacet, :func:`forest.render.path.materials.
    sheen_albedo_table`), E₁ the same GGX lobe's with F = 1: a white glossy BSDF of the same roughness weighted
    by s·F̄(μ) reflects what forest_path's lobe of weight s does, for exporters whose materials mix a glossy
    lobe over the leaf's diffuse ones.  Kept per α (parts of one recipe share it).
    """
    from ..render.path.materials import sheen_albedo_table

    e = sheen_albedo_table(alpha, n).astype(np.float64)
    e1 = sheen_albedo_table(alpha, n, fresnel=False).astype(np.float64)
    return tuple(round(float(v), 6) for v in e / np.maximum(e1, 1e-9))


def bark_colour(lod) -> np.ndarray | None:
    """The colour of a level's first bark part before the bark factor: base colour × mean texture detail.

    What :func:`canopy_colour` is to the leaves: materials that cannot multiply
    a texture by a per-tree colour show f_i × this.  None when no part is bark.
    """
    for part in lod.parts:
        if is_bark(part):
            return part_albedo(part)
    return None


def bark_factors(scene) -> np.ndarray | None:
    """Each tree's bark factor f_i (:meth:`forest.scene.Scene.bark_tints`): ``(N, 3)`` float32, row i the
    InstanceSet's row i, or None when every f_i is 1.

    Every exporter writes these rows beside the trees' colours and multiplies
    the ``bark`` parts' colour (× texture) by them; with None it writes no bark
    factor at all, so the files are those of a forest whose bark does not vary.
    """
    f = scene.bark_tints()
    if f is None:
        return None
    f = np.ascontiguousarray(f, dtype=np.float32).reshape(-1, 3)
    if len(f) != len(scene.instances):
        raise ForestError(f"bark factors: {len(f)} rows for {len(scene.instances)} trees")
    return f


def bound_radius(bound: np.ndarray) -> float:
    """Largest distance of a (2, 3) bound's corners from the object origin (the tree's base)."""
    b = np.asarray(bound, np.float64)
    corners = np.array([[b[i, 0], b[j, 1], b[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return float(np.linalg.norm(corners, axis=1).max())


def terrain_texture(scene) -> np.ndarray | None:
    """Linear RGB (H, W, 3) over the terrain (map convention): the ground's albedo grid the renderers use
    (``scene.terrain_albedo``: ``terrain_texture``, else ``[ground]``'s rules) times the fitted ``ground_tint``;
    None when the ground is one material (:func:`ground_colour`).  The grid's tileable detail texture is not
    exported."""
    rgb = np.asarray(scene.terrain_albedo.rgb, np.float32)
    if rgb.shape[0] * rgb.shape[1] == 1:
        return None
    gt = _ground_tint(scene)
    return rgb if gt is None else (rgb * gt).astype(np.float32)


def _ground_tint(scene) -> np.ndarray | None:
    """The Scene's fitted ground tint as float32 RGB, or None when it is 1 (nothing to multiply)."""
    gt = np.asarray(getattr(scene, "ground_tint", np.ones(3)), np.float32).reshape(3)
    return None if np.all(gt == 1.0) else gt


def ground_colour(scene) -> tuple[float, float, float]:
    """The ground's colour when it is one material: ``[render] terrain_colour`` times the fitted ``ground_tint``."""
    c = np.asarray(scene.config.render.terrain_colour, np.float64).reshape(3)
    gt = _ground_tint(scene)
    if gt is not None:
        c = c * gt.astype(np.float64)
    return (float(c[0]), float(c[1]), float(c[2]))


@dataclass(frozen=True)
class Horizon:
    """The far ground with its hills, as an exporter writes it (:func:`horizon`)."""

    vertices: np.ndarray  # (V, 3) float32, metres, Y up
    faces: np.ndarray  # (F, 3) uint32, wound upward
    normals: np.ndarray  # (V, 3) float32
    uv: np.ndarray  # (V, 2) float32: the map coordinates the terrain's uv would give them (outside [0, 1])
    colour: tuple[float, float, float]  # linear albedo: the far landscape's, times the fitted ground tint


def horizon(scene) -> Horizon | None:
    """The hills past the terrain's edge (``[render] horizon_hills``) as forest's renderers build them: the skirt
    out to the camera's far clip (:func:`forest.skirt.skirt_mesh`, :func:`forest.skirt.skirt_radius`) with the
    hills on it, coloured with the far landscape's albedo (:func:`forest.skirt.far_colour`) times the fitted
    ``ground_tint``.  None without hills or with ``horizon_ground = false``.  The woods' relief, their mosaic of
    woods and fields, steep rock and snow are forest_path's shading and stay there.  Still water at the terrain's
    edge runs on over the skirt as water (:func:`split_water`, with or without hills), not as part of the horizon."""
    from ..skirt import far_colour

    sk = _horizon_skirt(scene, sea=False)
    if sk is None:
        return None
    c = np.asarray(far_colour(scene.terrain_albedo), np.float64).reshape(3)
    gt = _ground_tint(scene)
    if gt is not None:
        c = c * gt.astype(np.float64)
    colour = (float(c[0]), float(c[1]), float(c[2]))
    return Horizon(
        np.asarray(sk.vertices, np.float32), np.asarray(sk.faces, np.uint32), sk.normals, _map_uv(scene, sk), colour
    )


def _map_uv(scene, sk) -> np.ndarray:
    """The map coordinates of a skirt's vertices (outside [0, 1] past the terrain's edge), float32 (V, 2)."""
    xmin, zmin, xmax, zmax = (float(v) for v in scene.terrain.extent)
    v = np.asarray(sk.vertices, np.float64)
    uv = np.stack([(v[:, 0] - xmin) / max(xmax - xmin, 1e-9), (v[:, 2] - zmin) / max(zmax - zmin, 1e-9)], 1)
    return uv.astype(np.float32)


def _horizon_skirt(scene, sea: bool | None = None):
    """The exported horizon's skirt (:func:`horizon`): None with ``horizon_ground = false``, and without hills
    except for its sea (the renderers' level far plain is not exported; the water on it is).
    ``sea``: only the faces still water covers past the terrain's edge (True; None when there are none) or only
    the others (False) — :mod:`forest.skirt`, "The sea"; None: all."""
    from ..skirt import Skirt, hills, sea_at_edge, sea_side, skirt_mesh, skirt_radius

    config, terrain = scene.config, scene.terrain
    h = hills(config)
    if not config.render.horizon_ground or (h is None and not sea):
        return None
    has_sea = sea is not None and sea_at_edge(terrain) is not None
    if sea and not has_sea:
        return None
    sk = skirt_mesh(terrain, skirt_radius(terrain.extent, float(config.camera.far)), h)
    if sk is None or not has_sea:
        return sk
    side = sea_side(sk, float(terrain.water[0]), bool(sea))
    if not len(side.faces):
        return None
    used, inverse = np.unique(side.faces, return_inverse=True)
    return Skirt(sk.vertices[used], inverse.reshape(-1, 3).astype(np.uint32), sk.normals[used])


@dataclass(frozen=True)
class Ground:
    """A ground mesh as an exporter writes it: the terrain, or the terrain less its water (:func:`split_water`)."""

    vertices: np.ndarray  # (V, 3), metres, Y up
    faces: np.ndarray  # (F, 3), wound upward
    normals: np.ndarray  # (V, 3)
    uv: np.ndarray  # (V, 2): map coordinates


@dataclass(frozen=True)
class Water:
    """The ground's water as its own surface (:func:`split_water`): a glossy dielectric over its painted colour."""

    vertices: np.ndarray  # (V, 3) float32, metres, Y up
    faces: np.ndarray  # (F, 3) uint32, wound upward
    normals: np.ndarray  # (V, 3) float32
    uv: np.ndarray  # (V, 2) float32: map coordinates
    colour: tuple[float, float, float]  # linear albedo of the body and bed: the painted water's mean, times ground_tint
    roughness: float  # the ripples as a microfacet roughness r, α = r² = tan(water_ripple)
    ior: float  # the surface's refractive index (1.33)


def split_water(scene) -> tuple[Ground, Water | None]:
    """The terrain's triangles split into dry ground and water (:func:`forest.ground.water_triangles`: the ground's
    water coverage at the centroid ≥ ½; ``[ground]`` rules of material ``water`` and ``[terrain] water``, the grid
    forest_path shades as its mirror).  The water's colour is :func:`forest.ground.water_colour` (times the fitted
    ``ground_tint``), its roughness :func:`forest.ground.water_roughness` of ``water_ripple``, its index 1.33.
    Without water the ground is the terrain's own arrays and the water None, so an export of a scene without water
    is what it was.  With still water at the terrain's edge (and ``horizon_ground``), the water runs on over the
    skirt's sea to the camera's far clip (:mod:`forest.skirt`, "The sea"), which the horizon (:func:`horizon`,
    written with hills) leaves out."""
    from ..config.schema import WATER_IOR
    from ..ground import water_colour, water_roughness, water_triangles

    terrain, albedo = scene.terrain, scene.terrain_albedo
    whole = Ground(terrain.vertices, terrain.faces, terrain.vertex_normals, terrain.uv)
    wet = water_triangles(terrain, albedo)
    sea = _horizon_skirt(scene, sea=True)
    if wet is None and sea is None:
        return whole, None
    faces = terrain.faces[wet] if wet is not None else np.zeros((0, 3), np.int64)
    used, inverse = np.unique(faces, return_inverse=True)
    verts = np.asarray(terrain.vertices[used], np.float32)
    tris = np.asarray(inverse.reshape(-1, 3), np.uint32)
    normals = np.asarray(terrain.vertex_normals[used], np.float32)
    uv = np.asarray(terrain.uv[used], np.float32)
    if sea is not None:
        tris = np.concatenate([tris, np.asarray(sea.faces, np.uint32) + np.uint32(len(verts))])
        verts = np.concatenate([verts, np.asarray(sea.vertices, np.float32)])
        normals = np.concatenate([normals, np.asarray(sea.normals, np.float32)])
        uv = np.concatenate([uv, _map_uv(scene, sea)])
    c = water_colour(albedo)
    gt = _ground_tint(scene)
    if gt is not None:
        c = c * gt.astype(np.float64)
    water = Water(
        verts,
        tris,
        normals,
        uv,
        (float(c[0]), float(c[1]), float(c[2])),
        water_roughness(float(scene.config.model.ground.water_ripple)),
        WATER_IOR,
    )
    if wet is None:
        return whole, water
    return Ground(terrain.vertices, terrain.faces[~wet], terrain.vertex_normals, terrain.uv), water


def look_instances(scene):
    """The Scene's trees with the fitted leaf tint folded into their colour column (:meth:`Scene.tree_tints`):
    what every exporter writes as a tree's colour.  The InstanceSet itself when no leaf tint is set."""
    tints = scene.tree_tints() if hasattr(scene, "tree_tints") else scene.instances.tint
    if tints is scene.instances.tint:
        return scene.instances
    import dataclasses

    return dataclasses.replace(scene.instances, tint=tints)
