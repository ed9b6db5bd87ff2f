"""Procedural rocks as library species: weathered boulders and stones for ground cover.

A preset with ``kind = "rock"`` and a ``[rock]`` table is drawn by this module
instead of the tree generator, so ``[[ground_cover]] model = "rock"`` (or
``[[species]] model = "rock@7"``) scatters boulders through the same pipeline as
plants: a rock is a species with one ``surface`` part and no textures.

**Shape.**  An icosphere (``trimesh.creation.icosphere``) of unit directions
``u`` is displaced along its normals to the radius

    r(u) = smin_k( 1 + a_l·F_l(u) + a_f·R_f(u),  min_i d_i / (n_i·u) )

* ``F_l`` — low-frequency lumps: 2 octaves of gradient noise at frequency
  ``lump_scale`` (Perlin 2002, "Improving noise", SIGGRAPH: lattice gradients,
  quintic fade 6t⁵ − 15t⁴ + 10t³), amplitude ``lumps``;
* ``R_f`` — finer facets: ``octaves`` octaves of *ridged* noise ``1 − 2|N|``
  from frequency ``facet_scale`` up (lacunarity 2, gain ½; Musgrave's ridged
  multifractal without the feedback, Ebert et al., *Texturing & Modeling*),
  amplitude ``facets`` — sharp creases and small flats rather than round bumps;
* fracture planes — ``cuts`` planes with random unit normals ``n_i`` at
  ``d_i = 1 − depth_i`` (``cut_depth``) from the centre: along ``u`` the plane
  lies at ``d_i / (n_i·u)`` (no cut where ``n_i·u ≤ 0``).  The smooth minimum
  ``smin_k(x) = −k·ln Σ exp(−x/k)`` (k = :data:`EDGE_ROUNDING`) rounds the edges
  the planes leave, as weathering does.  The planes are what make it a broken,
  weathered boulder instead of a potato.

The displaced sphere is stretched by ``elongation`` along X, then scaled so the
high level's horizontal extent along X is ``size`` and its height is
``flatten · size``, and lowered so ``sink`` of that height lies below ``y = 0``
(the rock sits *in* the ground: no daylight under it on a slope).  Every
``[lo, hi]`` range is drawn per seed as ``lo + (hi − lo)·U`` with ``U`` from
``np.random.Generator(PCG64(SeedSequence([seed, TAG])))``, so ``"rock@7"`` is
another rock of the same recipe and the individuals of a scene are different
stones.  The mesh is closed (the icosphere's topology is kept; ``r`` is clamped
above 0.2).

**Levels of detail** (:data:`BUDGETS`): ``high``, ``medium`` and ``low`` are the
icosphere at 4, 3 and 2 subdivisions (5 120, 1 280 and 320 triangles) under the
same displacement, each band-limited to what its vertices can carry (an octave
of frequency ``f`` is faded out between ``f_max / 2`` and ``f_max`` with
``f_max = 2^s / 2.2``, about one cycle per two edges of subdivision ``s``), so
a lower level is the smoothed rock rather than an aliased one; ``far`` is the
high level decimated by quadric error (:func:`forest.library.mesh.quadric_decimate`)
to at most :data:`FAR_TRIANGLES` triangles, within the library's far budget.

**Colour.**  One ``surface`` part per level, diffuse, no texture: its colour is
one of ``colours`` picked per seed, times ``1 + value_var·(2U − 1)``.  The
shipped preset's first colour is the ground's ``rock`` material,
weathered granite and gneiss (``forest.config.schema.GROUND_MATERIALS``: USGS
Spectral Library v7, Kokaly et al. 2017; ECOSTRESS, Meerdink et al. 2019;
scaled to Oke 1987's broadband albedos), so a boulder matches the rocky ground
around it.  ``tinted`` (default false) lets the scene's colour map multiply it.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ConfigError
from .mesh import MeshData, orient_faces, quadric_decimate, vertex_normals, write_ply

TAG = 0x50C4  # RNG stream tag of the rock generator
LODS = ("high", "medium", "low", "far")
SUBDIVISIONS = {"high": 4, "medium": 3, "low": 2}
FAR_TRIANGLES = 60
#: Triangles per level (inclusive): the icosphere's 20·4^s, the far level within the library's far budget.
BUDGETS = {"high": (2_000, 8_000), "medium": (500, 2_000), "low": (150, 500), "far": (12, 64)}
EDGE_ROUNDING = 0.04  # k of the smooth minimum, in units of the unit sphere's radius
MIN_RADIUS = 0.2
LUMP_OCTAVES = 2

#: Keys of the ``[rock]`` table and their defaults; lists of two numbers are ranges drawn per seed.
DEFAULTS: dict[str, Any] = {
    "size": [0.4, 1.2],
    "elongation": [1.0, 1.5],
    "flatten": [0.5, 0.75],
    "sink": 0.15,
    "lumps": 0.22,
    "lump_scale": 1.2,
    "facets": 0.07,
    "facet_scale": 3.0,
    "octaves": 3,
    "cuts": [4, 9],
    "cut_depth": [0.1, 0.35],
    "colours": [[0.22, 0.21, 0.19]],
    "value_var": 0.1,
    "tinted": False,
}
_RANGES = ("size", "elongation", "flatten", "cuts", "cut_depth")
_LIMITS: dict[str, tuple[float, float]] = {
    "size": (0.01, 50.0),
    "elongation": (1.0, 4.0),
    "flatten": (0.1, 2.0),
    "cuts": (0, 32),
    "cut_depth": (0.0, 0.6),
    "sink": (0.0, 0.6),
    "lumps": (0.0, 0.6),
    "lump_scale": (0.1, 8.0),
    "facets": (0.0, 0.3),
    "facet_scale": (0.5, 16.0),
    "octaves": (0, 6),
    "value_var": (0.0, 0.5),
}


def _num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def validate_recipe(recipe: dict, where: str = "recipe") -> dict:
    """Fill the defaults of a rock recipe and check it; raise :class:`ConfigError` naming the first bad field.

    Returns ``{"kind": "rock", "rock": {key: value}}`` with every key of :data:`DEFAULTS`.
    """
    if not isinstance(recipe, dict) or not isinstance(recipe.get("rock"), dict):
        raise ConfigError(where, "rock", "a rock preset needs a [rock] table")
    r_in = recipe["rock"]
    unknown = sorted(set(r_in) - set(DEFAULTS))
    if unknown:
        raise ConfigError(where, f"rock.{unknown[0]}", f"unknown key (expected one of: {', '.join(sorted(DEFAULTS))})")
    r: dict[str, Any] = dict(DEFAULTS)
    r.update(r_in)
    for key in DEFAULTS:
        v, f = r[key], f"rock.{key}"
        if key in _RANGES:
            lo, hi = _LIMITS[key]
            if not (isinstance(v, list) and len(v) == 2 and all(_num(x) for x in v) and lo <= v[0] <= v[1] <= hi):
                raise ConfigError(where, f, f"must be a range [lo, hi] with {lo:g} <= lo <= hi <= {hi:g}, got {v!r}")
            if key == "cuts" and not all(float(x).is_integer() for x in v):
                raise ConfigError(where, f, f"must be whole numbers, got {v!r}")
        elif key == "colours":
            if not (
                isinstance(v, list)
                and v
                and all(isinstance(c, list) and len(c) == 3 and all(_num(x) and 0 <= x <= 1 for x in c) for c in v)
            ):
                raise ConfigError(where, f, f"must be a list of RGB triples in [0, 1], got {v!r}")
        elif key == "tinted":
            if not isinstance(v, bool):
                raise ConfigError(where, f, f"must be true or false, got {v!r}")
        else:
            lo, hi = _LIMITS[key]
            if key == "octaves" and not (isinstance(v, int) and not isinstance(v, bool)):
                raise ConfigError(where, f, f"must be a whole number, got {v!r}")
            if not (_num(v) and lo <= v <= hi):
                raise ConfigError(where, f, f"must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return {"kind": "rock", "rock": r}


# ---------------------------------------------------------------------------
# Noise
# ---------------------------------------------------------------------------


class GradientNoise:
    """3-D gradient noise N(p) ∈ about [−1, 1] (Perlin 2002) with its own seeded lattice.

    256 random unit gradients and a permutation of 0‥255 drawn from ``rng``; the
    lattice point ``(i, j, k)`` takes gradient ``perm[(perm[(perm[i] + j)] + k)]``
    (indices mod 256), and N is the quintic-faded trilinear blend of the eight
    corners' ``g · (p − corner)``.
    """

    def __init__(self, rng: np.random.Generator):
        g = rng.normal(size=(256, 3))
        self.grad = g / np.linalg.norm(g, axis=1, keepdims=True)
        self.perm = rng.permutation(256).astype(np.int64)

    def __call__(self, p: np.ndarray) -> np.ndarray:
        """N at points ``p (n, 3)``; scaled by √2 so its range is about [−1, 1]."""
        p = np.asarray(p, dtype=np.float64)
        i0 = np.floor(p)
        f = p - i0
        i = i0.astype(np.int64)
        w = f * f * f * (f * (f * 6.0 - 15.0) + 10.0)
        out = np.zeros(len(p))
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    h = self.perm[
                        (self.perm[(self.perm[(i[:, 0] + dx) & 255] + i[:, 1] + dy) & 255] + i[:, 2] + dz) & 255
                    ]
                    d = f - np.array([dx, dy, dz], dtype=np.float64)
                    dot = np.einsum("ij,ij->i", self.grad[h], d)
                    wx = w[:, 0] if dx else 1.0 - w[:, 0]
                    wy = w[:, 1] if dy else 1.0 - w[:, 1]
                    wz = w[:, 2] if dz else 1.0 - w[:, 2]
                    out += wx * wy * wz * dot
        return out * math.sqrt(2.0)


def _band(freq: float, f_max: float) -> float:
    """Weight of an octave of frequency ``freq`` on a level that carries up to ``f_max``: 1 below f_max/2, 0 above."""
    return float(np.clip(2.0 - 2.0 * freq / f_max, 0.0, 1.0))


# ---------------------------------------------------------------------------
# Shape
# ---------------------------------------------------------------------------


class RockShape:
    """One rock drawn from a validated recipe and a seed: its radius field and its scale, colour and sink."""

    def __init__(self, recipe: dict, seed: int):
        r = recipe["rock"]
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, TAG])))

        def draw(key: str) -> float:
            lo, hi = r[key]
            return float(lo + (hi - lo) * rng.random())

        self.size = draw("size")
        self.elongation = draw("elongation")
        self.flatten = draw("flatten")
        n_cuts = int(round(draw("cuts")))
        c = rng.normal(size=(n_cuts, 3))
        self.cut_normals = c / np.maximum(np.linalg.norm(c, axis=1, keepdims=True), 1e-12)
        lo, hi = r["cut_depth"]
        self.cut_distances = 1.0 - (lo + (hi - lo) * rng.random(n_cuts))
        self.lump_noise = GradientNoise(rng)
        self.facet_noise = GradientNoise(rng)
        # A random rotation of the noise's domain, so lattice axes never line up with the rock's.
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        self.rotation = q
        self.offset = rng.uniform(0.0, 256.0, size=3)
        colours = r["colours"]
        base = np.asarray(colours[int(rng.integers(len(colours)))], dtype=np.float64)
        self.colour = np.clip(base * (1.0 + r["value_var"] * (2.0 * rng.random() - 1.0)), 0.0, 1.0)
        self.recipe = r

    def radius(self, u: np.ndarray, f_max: float = math.inf) -> np.ndarray:
        """r(u) of the module docstring at unit directions ``u (n, 3)``, octaves above ``f_max`` faded out."""
        r = self.recipe
        p = u @ self.rotation + self.offset
        rad = np.ones(len(u))
        for o in range(LUMP_OCTAVES):
            freq = r["lump_scale"] * 2.0**o
            rad += r["lumps"] * 0.5**o * _band(freq, f_max) * self.lump_noise(p * freq)
        for o in range(int(r["octaves"])):
            freq = r["facet_scale"] * 2.0**o
            wgt = r["facets"] * 0.5**o * _band(freq, f_max)
            if wgt > 0:
                rad += wgt * (1.0 - 2.0 * np.abs(self.facet_noise(p * freq + 17.0 * o)))
        if len(self.cut_normals):
            cos = u @ self.cut_normals.T
            t = np.where(cos > 1e-6, self.cut_distances[None, :] / np.maximum(cos, 1e-6), np.inf)
            k = EDGE_ROUNDING
            x = np.column_stack([rad, t])
            m = x.min(axis=1)
            rad = m - k * np.log(np.exp(-(x - m[:, None]) / k).sum(axis=1))
        return np.maximum(rad, MIN_RADIUS)

    def points(self, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
        """The displaced icosphere of ``subdivisions`` in the unit frame (before scaling): ``(vertices, faces)``."""
        import trimesh

        sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
        u = np.asarray(sphere.vertices, dtype=np.float64)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        f_max = 2.0**subdivisions / 2.2
        v = u * self.radius(u, f_max)[:, None]
        v[:, 0] *= self.elongation
        return v, np.asarray(sphere.faces, dtype=np.int64)


def build_meshes(recipe: dict, seed: int) -> tuple[dict[str, MeshData], np.ndarray]:
    """Draw a rock: ``({lod: MeshData}, colour)`` — Y up, metres, ``sink`` of its height below ``y = 0``."""
    shape = RockShape(recipe, seed)
    raw = {lod: shape.points(s) for lod, s in SUBDIVISIONS.items()}
    hv = raw["high"][0]
    ext = np.ptp(hv, axis=0)
    scale = np.array([shape.size / ext[0], shape.flatten * shape.size / ext[1], shape.size / ext[0]])
    height = shape.flatten * shape.size
    centre = 0.5 * (hv.max(axis=0) + hv.min(axis=0)) * scale
    shift = np.array([centre[0], hv[:, 1].min() * scale[1] + shape.recipe["sink"] * height, centre[2]])
    meshes: dict[str, MeshData] = {}
    for lod, (v, f) in raw.items():
        v = (v * scale - shift).astype(np.float32)
        meshes[lod] = _mesh(v, f)
    far = quadric_decimate(meshes["high"], FAR_TRIANGLES)
    meshes["far"] = _mesh(far.vertices, far.faces)
    return meshes, shape.colour


def _mesh(vertices: np.ndarray, faces: np.ndarray) -> MeshData:
    """A closed rock surface: area-weighted normals, faces wound about them, ``uv = (x, z)`` metres."""
    v = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces, dtype=np.uint32)
    uv = np.ascontiguousarray(v[:, [0, 2]], dtype=np.float32)
    return orient_faces(MeshData(v, f, vertex_normals(v, f), uv))


# ---------------------------------------------------------------------------
# Species files
# ---------------------------------------------------------------------------

_CODE_FILES = ("rocks.py", "mesh.py", "build.py", "preview.py")


def code_hash() -> str:
    """Hash of this generator's source (and the shared mesh/preview code): edits rebuild rocks."""
    from .build import source_hash

    return source_hash(_CODE_FILES)


def recipe_hash(recipe: dict, seed: int) -> str:
    """The cache key of a rock species (see :func:`forest.library.build.recipe_digest`)."""
    from .build import recipe_digest

    return recipe_digest(code_hash(), recipe, seed)


def generate(recipe: dict, seed: int, out: Path, *, name: str, where: str = "recipe") -> dict:
    """Draw the rock ``recipe`` with ``seed`` and write every level of detail into folder ``out``.

    Writes ``<lod>_rock.ply`` and ``species.json`` (last); returns the ``species.json`` dictionary.
    """
    from .build import lod_entry, part_entry, write_json

    recipe = validate_recipe(recipe, where)
    meshes, colour = build_meshes(recipe, seed)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lods = []
    for lod in LODS:
        file = f"{lod}_rock.ply"
        write_ply(out / file, meshes[lod])
        part = part_entry("surface", file, meshes[lod], colour, None, recipe["rock"]["tinted"], 0.0)
        lods.append(lod_entry(lod, [part]))
    meta = {
        "name": name,
        "source": "generated",
        "seed": int(seed),
        "hash": recipe_hash(recipe, seed),
        "kind": "rock",
        "lods": lods,
    }
    write_json(out / "species.json", meta)
    return meta
