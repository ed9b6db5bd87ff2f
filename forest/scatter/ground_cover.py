"""Ground cover: grass and fern clumps scattered near the camera at a density per square metre.

Each ``[[ground_cover]]`` j is scattered like the trees — sites uniform by
surface area, the shared rules, the same attributes — but only where the
camera can see a small plant: within ``max_distance`` of its path.

* **Region** — the camera path is sampled every ``max_distance / 32`` along
  its keys (:func:`camera_path_points`; one point for a still camera).  The
  terrain faces whose centroid lies within ``max_distance`` + the face's own
  radius of a path point are the region; its true area A is summed.
* **Sites** — n = round(density · A) candidates, uniform by area over the
  region (a face with probability ∝ area, a point in it by the square-root
  warp, as :meth:`forest.terrain.Terrain.sample_points`), so the expected
  number of plants per square metre of surface is ``density`` wherever the
  rules keep them.
* **Rules**, in order: the distance d to the path (to the densely sampled
  path, so exact to ``max_distance / 64``) thins the plants smoothly to none
  at ``max_distance`` — kept where ξ_fade < f(d) = 1 − s((d − (1 − φ)R)/(φR)),
  with R = ``max_distance``, φ = :data:`FADE` and s the smoothstep, so the
  density is ``density`` up to 0.7 R and there is no visible edge where the
  cover ends; then outside ``[maps] presence`` (with ``presence = true``),
  outside the slope window [``slope_min``, ``slope_max``] or the
  ``altitude`` window; and on still water (``[terrain] water``) or within its
  ``shore`` metres above it — or, with ``water_edge = true`` (reeds, sedges),
  only on the water itself (its coverage ≥ ½: within ``SHORE_RAMP``/2 of the
  level), so the cover grows down to the waterline.
* **Patches** (``clumping = {strength, scale, size}``; off at the default
  strength 0).  A meadow is not an even lawn: its grasses grow in patches.
  The stand field of :mod:`forest.scatter.canopy` — fBm value noise at
  wavelength λ = ``scale``, replaced by its area rank U ∈ [0, 1] over the
  region's X/Z bounding box, seeded by ``SeedSequence([seed, CLUMP_TAG, TAG,
  j])`` so each entry has its own patches, independent of the trees' stands —
  sets the density

      ρ(x) = density · (1 + s(2U(x) − 1)),   s = ``strength``,

  from (1 − s) to (1 + s) times ``density``, with mean ``density`` because U is
  uniform over the area.  To draw it, (1 + s) times as many candidates are
  placed and each is kept with the extra probability (1 + s(2U − 1))/(1 + s)
  (thinning a Poisson process, Lewis & Shedler 1979).  With ``size`` = z a
  plant's scale is multiplied by 1 + z(2U − 1): tall lush patches, short
  sparse ones.  With s = 0 nothing is drawn or changed (the same plants as
  without the option, byte for byte).
* **Edge band** (``edge`` = W metres; off by default): only plants within W of
  the edge of the presence map (the contour where it crosses
  ``[maps] presence_threshold``) are kept, on both sides of it — a shrub mantle
  that softens the wall of trunks at a forest edge.  The distance δ to the edge
  is a signed Euclidean distance transform of the thresholded map (to the
  nearest pixel of the other kind, less half a pixel, bilinear between pixel
  centres; exact to about half a map pixel) and plants are kept where
  ξ_fade < 1 − s((δ − W/2)/(W/2)) (s the smoothstep): the full density up to
  W/2 from the edge, none beyond W.  ``presence = true`` keeps only the
  band's inner side.  It needs ``[maps] presence``.
* **Attributes** — yaw, scale in ``scale``, wind phase, individual, tilt by
  ``align`` towards the terrain normal, tint (:mod:`forest.tint`) and
  partition, as trees get them (:mod:`forest.scatter.attributes`).

The rules, the patches and the edge band multiply into one keep probability
tested against the ``fade`` stream's one uniform per candidate.

Random numbers: one generator per quantity of :data:`STREAMS` spawned from
``SeedSequence([seed, TAG, j])``, one value per candidate, so entries are
independent of each other and of the trees' streams.  Ids follow the trees'
(which are < ``[scatter] count``): candidate i of entry j has id
``count + o_j + i`` with o_j the candidates of the entries before it, so rows
stay sorted by id and ids stay small (an EXR's float id layer holds them
exactly up to 2²⁴).  Moving the camera re-draws the ground cover; it never
moves a tree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..camera import camera_at
from ..config import Config
from ..config.schema import MAX_TREES, CameraConfig, GroundCoverConfig
from ..errors import ConfigError
from ..instances import COLUMNS, yaw_tilt_quaternion
from ..maps import MapSet
from ..terrain import SHORE_RAMP, Terrain
from ..tint import TintParams, Where
from .attributes import draw_individuals
from .candidates import SLOPE_TOLERANCE, outside, slope_degrees
from .canopy import smoothstep, stand_field

TAG = 0x6C0BE4
STREAMS = ("position", "yaw", "scale", "phase", "individual", "fade")
FADE = 0.3  # the outer share of max_distance over which the density falls to 0
PATH_SAMPLES_PER_DISTANCE = 32  # path points per max_distance of camera travel
MAX_PATH_POINTS = 200_000


@dataclass
class CoverResult:
    """One ``[[ground_cover]]`` entry's rows (InstanceSet columns) and its counts for the report."""

    name: str
    candidates: int
    columns: dict[str, np.ndarray]

    @property
    def kept(self) -> int:
        """Number of ground-cover rows kept."""
        return len(self.columns["id"])


def camera_path_points(camera: CameraConfig, spacing: float) -> np.ndarray:
    """Points along the camera's path ``(P, 3)``: the still position, or the keyed path every ≤ ``spacing`` m.

    The path is evaluated with :func:`forest.camera.camera_at` at frames refined
    until consecutive points are at most ``spacing`` apart (capped at
    :data:`MAX_PATH_POINTS`).
    """
    if not camera.keys:
        return np.asarray(camera_at(camera, 0.0).position, dtype=np.float64)[None, :]
    frames = np.array([k.frame for k in camera.keys], dtype=np.float64)
    t = frames
    while True:
        pts = np.array([camera_at(camera, float(f)).position for f in t], dtype=np.float64)
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1) if len(pts) > 1 else np.zeros(0)
        if not len(step) or step.max() <= spacing or len(t) * 2 > MAX_PATH_POINTS:
            return pts
        # Split every interval that is too long into enough pieces.
        pieces = np.maximum(np.ceil(step / spacing).astype(np.int64), 1)
        t = np.concatenate([np.linspace(a, b, m, endpoint=False) for a, b, m in zip(t[:-1], t[1:], pieces)] + [t[-1:]])


def region_faces(terrain: Terrain, path: cKDTree, max_distance: float, slack: float) -> np.ndarray:
    """Indices of the faces that may hold a point within ``max_distance`` of the path (centroid test + radius)."""
    f = terrain.faces
    v = terrain.vertices
    centroid = (v[f[:, 0]] + v[f[:, 1]] + v[f[:, 2]]) / 3.0
    radius = np.max([np.linalg.norm(v[f[:, k]] - centroid, axis=1) for k in range(3)], axis=0)
    d, _ = path.query(centroid, distance_upper_bound=max_distance + radius.max() + slack)
    return np.flatnonzero(d <= max_distance + radius + slack)


def scatter_cover(
    j: int,
    cover: GroundCoverConfig,
    species_index: int,
    first_id: int,
    config: Config,
    terrain: Terrain,
    maps: MapSet,
    tints: TintParams,
) -> CoverResult:
    """Scatter ``[[ground_cover]][j]`` (module docstring): its rows as InstanceSet columns."""
    name = cover.name or cover.model
    spacing = cover.max_distance / PATH_SAMPLES_PER_DISTANCE
    points = camera_path_points(config.camera, spacing)
    tree = cKDTree(points)
    faces = region_faces(terrain, tree, cover.max_distance, spacing)
    area = float(terrain.face_areas[faces].sum()) if len(faces) else 0.0
    s = cover.clumping.strength
    n = int(round(cover.density * area * (1.0 + s)))  # (1 + s) candidates per plant for the patches (docstring)
    if n > MAX_TREES:
        raise ConfigError(
            config.path,
            f"ground_cover[{j}].density",
            f"would place about {n:,} plants within {cover.max_distance:g} m of the camera path "
            f"({area / 1e6:.3f} km²); at most {MAX_TREES:,}: lower density or max_distance",
        )
    if n == 0:
        return CoverResult(name, 0, empty_columns())
    seeds = np.random.SeedSequence([config.seed, TAG, j]).spawn(len(STREAMS))
    rng = {s: np.random.Generator(np.random.PCG64(q)) for s, q in zip(STREAMS, seeds)}
    xi = rng["position"].random((3, n))
    sub = Terrain(terrain.vertices, terrain.faces[faces])
    position, face, bary = sub.sample_points(xi[0], xi[1], xi[2])
    normal = terrain.normals_at(faces[face], bary)
    u, v = terrain.to_uv(position[:, 0], position[:, 2])
    d, _ = tree.query(position)
    p = fade(d, cover.max_distance)
    rank = None
    if s > 0 or cover.clumping.size > 0:
        rank = patch_rank(cover, j, config.seed, terrain, faces, position)
    if rank is not None and s > 0:
        p = p * patch_keep(rank, s)
    if cover.edge is not None:
        p = p * edge_keep(presence_edge_distance(maps, config, j, u, v, terrain.extent), cover.edge)
    keep = rng["fade"].random(n) < p
    if cover.presence:
        keep &= maps.present(u, v)
    keep &= terrain.dry(position[:, 1], SHORE_RAMP / 2.0 if cover.water_edge else None)
    slope_lo, slope_hi = np.full(n, cover.slope_min), np.full(n, cover.slope_max)
    keep &= ~outside(slope_degrees(normal), slope_lo, slope_hi, SLOPE_TOLERANCE)
    if cover.altitude is not None:
        keep &= ~outside(position[:, 1], np.full(n, cover.altitude[0]), np.full(n, cover.altitude[1]))
    sel = np.flatnonzero(keep)
    yaw = rng["yaw"].random(n)[sel] * (2 * np.pi)
    scale = rng["scale"].random(n)[sel]
    phase = rng["phase"].random(n)[sel] * (2 * np.pi)
    individual = draw_individuals(rng["individual"].random(n)[sel], np.full(len(sel), cover.individual_count))
    pos32 = position[sel].astype(np.float32)
    k = np.full(len(sel), species_index, dtype=np.int64)
    ids = (first_id + sel).astype(np.uint64)
    lo, hi = cover.scale
    columns = {
        "id": ids,
        "position": pos32,
        "rotation": yaw_tilt_quaternion(yaw, normal[sel], np.full(len(sel), cover.align)),
        "yaw": yaw,
        "scale": (lo + (hi - lo) * scale) * (1.0 if rank is None else patch_size(rank[sel], cover.clumping.size)),
        "species": k,
        "tint": tints.tints(
            maps.tint_at(pos32[:, 0], pos32[:, 2], terrain.extent), k, ids, Where.of(pos32, terrain.extent)
        ),
        "partition": maps.partition_at(u[sel], v[sel]),
        "normal": normal[sel],
        "phase": phase,
        "individual": individual,
    }
    return CoverResult(name, n, {c: np.asarray(a, dtype=COLUMNS[c][0]) for c, a in columns.items()})


def patch_rank(
    cover: GroundCoverConfig, j: int, seed: int, terrain: Terrain, faces: np.ndarray, position: np.ndarray
) -> np.ndarray:
    """The patch field's area rank U at ``position`` (module docstring): entry ``j``'s own stand field over the region."""
    v = terrain.vertices[np.unique(terrain.faces[faces])]
    extent = (v[:, 0].min(), v[:, 2].min(), v[:, 0].max(), v[:, 2].max())
    field = stand_field(extent, cover.clumping.scale, seed, (TAG, j))
    return field.at(position[:, 0], position[:, 2])


def patch_keep(rank: np.ndarray, strength: float) -> np.ndarray:
    """Extra keep probability (1 + s(2U − 1))/(1 + s) of a candidate at patch rank U (of (1 + s)× as many)."""
    return (1.0 + strength * (2.0 * rank - 1.0)) / (1.0 + strength)


def patch_size(rank: np.ndarray, size: float) -> np.ndarray:
    """Scale factor 1 + z(2U − 1) of a plant at patch rank U for ``clumping.size`` z."""
    return 1.0 + size * (2.0 * np.asarray(rank, np.float64) - 1.0)


def presence_edge_distance(
    maps: MapSet, config: Config, j: int, u: np.ndarray, v: np.ndarray, extent: tuple[float, float, float, float]
) -> np.ndarray:
    """Distance, metres, from map points (u, v) to the presence map's edge (its threshold contour), either side
    (:meth:`forest.maps.MapSet.edge_distance`, unsigned); ∞ everywhere when the map has no edge (all present)."""
    if maps.presence is None:
        raise ConfigError(config.path, f"ground_cover[{j}].edge", "needs [maps] presence: the band follows its edge")
    return np.abs(maps.edge_distance(u, v, extent))


def edge_keep(distance: np.ndarray, width: float) -> np.ndarray:
    """Keep probability in the edge band: 1 up to ``width``/2 from the edge, smoothly 0 at ``width`` and beyond."""
    return 1.0 - smoothstep(0.5 * width, width, distance)


def fade(d: np.ndarray, reach: float) -> np.ndarray:
    """Share of the density kept at distance ``d``: 1 up to (1 − FADE)·reach, smoothly 0 at ``reach`` and beyond."""
    t = np.clip((np.asarray(d, np.float64) - (1.0 - FADE) * reach) / (FADE * reach), 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


def empty_columns() -> dict[str, np.ndarray]:
    """InstanceSet columns with no rows."""
    return {k: np.zeros((0, *shape), dtype=dtype) for k, (dtype, shape) in COLUMNS.items()}


def scatter_ground_cover(config: Config, terrain: Terrain, maps: MapSet, tints: TintParams) -> list[CoverResult]:
    """Every ``[[ground_cover]]`` entry scattered (species indices after the ``[[species]]``), ids after the trees'."""
    out = []
    first = config.scatter.count
    for j, cover in enumerate(config.model.ground_cover):
        r = scatter_cover(j, cover, len(config.species) + j, first, config, terrain, maps, tints)
        first += r.candidates
        out.append(r)
    return out
