"""Terrain: a triangle mesh over the X/Z plane (Y up, metres) with heights, normals and slope.

Three sources, one representation:

* ``heightmap`` — an image (8/16-bit PNG, TIFF, EXR) whose pixels become a
  regular grid of vertices spanning ``size`` metres, centred on the origin;
  white is ``height`` metres.
* ``mesh`` — any triangle mesh trimesh reads, already in metres with Y up.
* ``procedural`` — fractal value noise (fBm): ``octaves`` lattices, each twice
  as fine and ``roughness`` times as strong as the previous one.

Maps are laid over the terrain's X/Z extent as textures seen from above:
image column → +X, image row → +Z (row 0 at the smallest Z).  A map pixel
(i, j) of an H×W image covers x ∈ xmin + [j, j+1]·Δx, z ∈ zmin + [i, i+1]·Δz.

Placement samples the *surface* uniformly by area (:meth:`Terrain.sample_points`),
so the number of trees per square metre does not depend on how the terrain is
parametrised or triangulated.

**Still water** (``[terrain] water = { level, shore }``, :func:`flood`): every vertex below the
level is raised to it, y ← max(y, level), so a lake's (or the sea's) surface is part of the one
terrain mesh every renderer and exporter already draws — flat, at one height, its shoreline the
level's contour on the mesh.  The ground paints it with the ``water`` material
(:meth:`Terrain.water_cover`, :mod:`forest.ground`) and scatter keeps trees and ground cover off
it and ``shore`` metres above it (:meth:`Terrain.dry`).  The flooded terrain keeps the terrain it
flooded as its ``bed``, so the water's depth is known wherever it stands (:meth:`Terrain.water_depth`):
the ground shows the bed through shallow water (:mod:`forest.ground`, "Shallow water").
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path

import numpy as np

from .config import TerrainConfig
from .errors import ForestError
from .parallel import rowwise

MAX_MESH_BYTES = 1024 * 1024 * 1024
MAX_GRID = 4097
#: Metres over which the ground turns from water to shore above the water's level (:meth:`Terrain.water_cover`):
#: the flooded surface is at the level exactly, so only the shore's own triangles rise through this band.
SHORE_RAMP = 0.05


class Terrain:
    """A triangle mesh terrain.  ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64."""

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        *,
        grid_shape: tuple[int, int] | None = None,
        source: str = "mesh",
        water: tuple[float, float] | None = None,
        bed: Terrain | None = None,
    ):
        #: Still water as (level, shore) metres (:func:`flood`), None without.
        self.water = water
        #: The terrain as it was before :func:`flood` raised it to the water's level (None when not flooded).
        self.bed = bed
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.grid_shape = grid_shape  # (rows along Z, columns along X) for grid terrains
        self.source = source
        lo = self.vertices.min(axis=0)
        hi = self.vertices.max(axis=0)
        self.extent = (float(lo[0]), float(lo[2]), float(hi[0]), float(hi[2]))  # xmin, zmin, xmax, zmax
        self.height_range = (float(lo[1]), float(hi[1]))

    # -- geometry --------------------------------------------------------------
    @cached_property
    def _cross(self) -> np.ndarray:
        v = self.vertices
        f = self.faces
        return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])

    @cached_property
    def face_areas(self) -> np.ndarray:
        """True 3-D area of each triangle, m²."""
        return 0.5 * np.linalg.norm(self._cross, axis=1)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit face normals, each oriented upwards (+Y)."""
        n = self._cross.copy()
        # Orient every face upwards (terrains are height fields or close to it).
        n[n[:, 1] < 0] *= -1.0
        return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)

    @cached_property
    def vertex_normals(self) -> np.ndarray:
        """Area-weighted vertex normals (smooth shading, tree alignment)."""
        acc = np.zeros_like(self.vertices)
        n = self.face_normals * (2.0 * self.face_areas)[:, None]
        # Scatter-add with bincount per component (np.add.at is ~20× slower).
        for c in range(3):
            acc[:, c] = sum(
                np.bincount(self.faces[:, k], weights=n[:, c], minlength=len(self.vertices)) for k in range(3)
            )
        norm = np.linalg.norm(acc, axis=1, keepdims=True)
        acc = np.where(norm > 0, acc / np.maximum(norm, 1e-300), np.array([0.0, 1.0, 0.0]))
        return acc

    @property
    def area(self) -> float:
        """Total surface area (m²)."""
        return float(self.face_areas.sum())

    @cached_property
    def _guide(self) -> tuple[np.ndarray, np.ndarray]:
        """Area CDF over faces and a guide table (Chen & Asau 1974) for O(1) inverse-CDF lookups."""
        c = np.cumsum(self.face_areas)
        cdf = c / c[-1]
        m = len(cdf)
        guide = np.searchsorted(cdf, np.arange(m) / m, side="right")
        return cdf, guide

    def pick_faces(self, u: np.ndarray) -> np.ndarray:
        """Faces with probability ∝ area from uniform ``u`` (guide-table inverse CDF, exact)."""
        cdf, guide = self._guide
        m = len(cdf)
        i = guide[np.minimum((u * m).astype(np.int64), m - 1)]
        # Walk forward while cdf[i] <= u; on average under one step per sample.
        todo = np.flatnonzero((cdf[i] <= u) & (i < m - 1))
        while len(todo):
            i[todo] += 1
            todo = todo[(cdf[i[todo]] <= u[todo]) & (i[todo] < m - 1)]
        return i

    @cached_property
    def uv(self) -> np.ndarray:
        """Per-vertex texture coordinates over the X/Z extent (u → +X, v → +Z)."""
        return np.stack(self.to_uv(self.vertices[:, 0], self.vertices[:, 2]), axis=1)

    def to_uv(self, x: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World X/Z → map coordinates in [0, 1] (u along X, v along Z)."""
        xmin, zmin, xmax, zmax = self.extent
        return (np.asarray(x) - xmin) / max(xmax - xmin, 1e-12), (np.asarray(z) - zmin) / max(zmax - zmin, 1e-12)

    # -- sampling ----------------------------------------------------------------
    def sample_points(self, u_face: np.ndarray, u1: np.ndarray, u2: np.ndarray):
        """Area-uniform points: returns (positions (N, 3), faces (N,), barycentrics (N, 3)).

        A triangle is chosen with probability proportional to its area, then a
        point in it by the square-root warp (Osada et al. 2002):
        b0 = 1 − √u1, b1 = √u1 (1 − u2), b2 = √u1 u2.
        """
        if len(self.faces) == 0 or self.area <= 0:
            raise ForestError("terrain has no area")
        self._guide  # noqa: B018  (built once here, not by several threads at once)
        return rowwise(self._sample_rows, np.asarray(u_face), np.asarray(u1), np.asarray(u2))

    def _sample_rows(self, u_face: np.ndarray, u1: np.ndarray, u2: np.ndarray):
        face = self.pick_faces(u_face)
        su = np.sqrt(u1)
        b = np.empty((len(face), 3))
        b[:, 1] = su * (1.0 - u2)
        b[:, 2] = su * u2
        b[:, 0] = 1.0 - su
        f = self.faces[face]
        v = self.vertices
        pos = v[f[:, 0]] * b[:, :1] + v[f[:, 1]] * b[:, 1:2] + v[f[:, 2]] * b[:, 2:]
        return pos, face, b

    def normals_at(self, face: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Interpolated (smooth) unit normals at barycentric points (split over the cores for many)."""
        self.vertex_normals  # noqa: B018  (built once here, not by several threads at once)
        return rowwise(self._normal_rows, np.asarray(face), np.asarray(b))

    def _normal_rows(self, face: np.ndarray, b: np.ndarray) -> np.ndarray:
        f = self.faces[face]
        vn = self.vertex_normals
        nrm = vn[f[:, 0]] * b[:, :1] + vn[f[:, 1]] * b[:, 1:2] + vn[f[:, 2]] * b[:, 2:]
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        return nrm

    # -- water -------------------------------------------------------------------
    def dry(self, y: np.ndarray, shore: float | None = None) -> np.ndarray:
        """Whether heights ``y`` stand more than ``shore`` metres above the water (all True without water);
        ``shore`` None: the water's own (``[terrain] water`` ``shore``)."""
        y = np.asarray(y, dtype=np.float64)
        if self.water is None:
            return np.ones(y.shape, dtype=bool)
        level, own = self.water
        return y > level + (own if shore is None else float(shore))

    def water_cover(self, height: np.ndarray) -> np.ndarray | None:
        """The water's coverage W ∈ [0, 1] of ground at heights ``height`` (the flooded mesh's):
        W = 1 − s((h − level) / :data:`SHORE_RAMP`), s the smoothstep; None without water."""
        if self.water is None:
            return None
        t = np.clip((np.asarray(height, dtype=np.float64) - self.water[0]) / SHORE_RAMP, 0.0, 1.0)
        return 1.0 - t * t * (3.0 - 2.0 * t)

    def water_depth(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Metres of still water over the bed at world X/Z: max(level − h_bed(x, z), 0), h_bed the unflooded
        terrain's height (:attr:`bed`); zeros without water."""
        x = np.asarray(x, dtype=np.float64)
        if self.water is None or self.bed is None:
            return np.zeros(x.shape)
        z = np.asarray(z, dtype=np.float64)
        return np.maximum(self.water[0] - self.bed.height_at(x.ravel(), z.ravel()).reshape(x.shape), 0.0)

    # -- queries -------------------------------------------------------------------
    def height_at(self, x, z) -> np.ndarray:
        """Terrain height at world X/Z (vectorised).  Outside the extent: clamped to the edge."""
        x = np.atleast_1d(np.asarray(x, dtype=np.float64))
        z = np.atleast_1d(np.asarray(z, dtype=np.float64))
        if self.grid_shape is not None:
            rows, cols = self.grid_shape
            u, v = self.to_uv(x, z)
            fx = np.clip(u, 0, 1) * (cols - 1)
            fz = np.clip(v, 0, 1) * (rows - 1)
            j = np.minimum(fx.astype(np.int64), cols - 2)
            i = np.minimum(fz.astype(np.int64), rows - 2)
            tx, tz = fx - j, fz - i
            h = self.vertices[:, 1].reshape(rows, cols)
            h00, h01, h10, h11 = h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]
            # Same split as the triangulation: (00, 10, 11) and (00, 11, 01).
            lower = tz >= tx
            return np.where(lower, h00 + tz * (h10 - h00) + tx * (h11 - h10), h00 + tx * (h01 - h00) + tz * (h11 - h01))
        import trimesh

        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False)
        top = self.height_range[1] + 1.0
        origins = np.stack([x, np.full_like(x, top), z], axis=1)
        dirs = np.tile([0.0, -1.0, 0.0], (len(x), 1))
        locs, idx, _ = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
        out = np.full(len(x), self.height_range[0])
        out[idx] = locs[:, 1]
        return out


# ---------------------------------------------------------------------------
# Builders
# ---------------------------------------------------------------------------


def grid_terrain(heights: np.ndarray, size: tuple[float, float], source: str = "grid") -> Terrain:
    """Triangulate a (rows, cols) height grid spanning ``size`` = (X, Z) metres, centred at 0."""
    rows, cols = heights.shape
    if rows < 2 or cols < 2:
        raise ForestError("terrain grid needs at least 2×2 samples")
    sx, sz = size
    xs = np.linspace(-sx / 2, sx / 2, cols)
    zs = np.linspace(-sz / 2, sz / 2, rows)
    X, Z = np.meshgrid(xs, zs)
    verts = np.stack([X.ravel(), heights.ravel().astype(np.float64), Z.ravel()], axis=1)
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    # Counter-clockwise seen from above (+Y) so normals point up: (a, c, d), (a, d, b).
    faces = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
    return Terrain(verts, faces, grid_shape=(rows, cols), source=source)


def fbm_heights(resolution: int, octaves: int, roughness: float, seed: int) -> np.ndarray:
    """Fractal value noise in [0, 1] on a resolution × resolution grid (deterministic)."""
    from scipy.ndimage import map_coordinates

    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, 0x7E77A1])))
    out = np.zeros((resolution, resolution))
    amp, total = 1.0, 0.0
    t = np.linspace(0.0, 1.0, resolution)
    for o in range(octaves):
        n = 2 ** (o + 1) + 1
        lattice = rng.random((n + 2, n + 2))
        coords = t * (n - 1) + 1.0
        ii, jj = np.meshgrid(coords, coords, indexing="ij")
        out += amp * map_coordinates(lattice, [ii, jj], order=3, mode="nearest")
        total += amp
        amp *= roughness
    out /= total
    lo, hi = out.min(), out.max()
    return (out - lo) / max(hi - lo, 1e-12)


def flood(terrain: Terrain, level: float, shore: float = 0.0) -> Terrain:
    """The terrain under still water at ``level`` metres: y ← max(y, level) (module docstring), ``water`` set and
    the unflooded terrain kept as its ``bed``."""
    v = terrain.vertices.copy()
    np.maximum(v[:, 1], level, out=v[:, 1])
    return Terrain(
        v, terrain.faces, grid_shape=terrain.grid_shape, source=terrain.source, water=(level, shore), bed=terrain
    )


def load_terrain(cfg: TerrainConfig, config_path: Path | None = None) -> Terrain:
    """Build the :class:`Terrain` a ``[terrain]`` section describes (flooded to its ``water`` level if it has one)."""
    terrain = _load_source(cfg, config_path)
    if cfg.water is None:
        return terrain
    return flood(terrain, cfg.water.level, cfg.water.shore)


def _load_source(cfg: TerrainConfig, config_path: Path | None = None) -> Terrain:
    """The terrain of the section's one source, as it is."""
    where = f"{config_path}: terrain" if config_path else "terrain"
    if cfg.flat is not None:
        return grid_terrain(np.zeros((2, 2)), (cfg.flat.size, cfg.flat.size), source="flat")
    if cfg.procedural is not None:
        pr = cfg.procedural
        seed = 0 if pr.seed is None else pr.seed
        h = fbm_heights(pr.resolution, pr.octaves, pr.roughness, seed) * pr.height
        return grid_terrain(h, (pr.size, pr.size), source="procedural")
    if cfg.kind == "heightmap":
        assert cfg.heightmap is not None  # the schema requires it for this kind
        from .images import read_map_grey

        try:
            g = read_map_grey(cfg.heightmap, what="heightmap")
        except ForestError as e:
            raise ForestError(f"{where}.heightmap: {e}") from None
        if g.shape[0] > MAX_GRID or g.shape[1] > MAX_GRID:
            raise ForestError(
                f"{where}.heightmap: {cfg.heightmap} is {g.shape[1]}x{g.shape[0]}, over the {MAX_GRID}x{MAX_GRID} limit"
            )
        if g.shape[0] < 2 or g.shape[1] < 2:
            raise ForestError(f"{where}.heightmap: {cfg.heightmap} must be at least 2x2 pixels")
        return grid_terrain(g * cfg.height, cfg.size, source="heightmap")
    assert cfg.mesh is not None  # the schema requires it for this kind
    return load_mesh_terrain(cfg.mesh, where=f"{where}.mesh")


def load_mesh_terrain(path: Path, where: str = "terrain.mesh") -> Terrain:
    """A terrain from a mesh file (any format trimesh reads); missing, oversized, empty or non-finite meshes raise
    ``ForestError`` naming ``where``.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise ForestError(f"{where}: file not found: {path}")
    if path.stat().st_size > MAX_MESH_BYTES:
        raise ForestError(f"{where}: {path} is over the {MAX_MESH_BYTES // 2**20} MiB limit")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:
        raise ForestError(f"{where}: cannot read {path}: {e}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ForestError(f"{where}: {path} has no triangles")
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    if not np.isfinite(v).all():
        raise ForestError(f"{where}: {path} has NaN or infinite vertices")
    from .config.schema import WORLD_METRES

    if np.abs(v).max() > WORLD_METRES:
        raise ForestError(
            f"{where}: {path} has vertices up to {np.abs(v).max():.3g} m from the origin, beyond ±{WORLD_METRES:g} m"
        )
    t = Terrain(v, f, source="mesh")
    if t.area <= 0:
        raise ForestError(f"{where}: {path} has zero surface area")
    return t
