"""A parametric tree generator in the spirit of Weber & Penn (1995).

J. Weber and J. Penn, "Creation and rendering of realistic trees", SIGGRAPH 1995.
A tree is a hierarchy of *stems*: level 0 are trunks (or the fronds of a ground
clump), each stem of level ``L`` carries ``branches`` children of level ``L+1``,
and the stems of the last level carry leaves.  Every stem of a level is grown
at once as numpy arrays ``(S, P, 3)`` (``S`` stems, ``P = segments + 1`` points).

Per stem (all angles in degrees, as in the paper):

* **Curvature** — the heading ``d`` turns about the stem's side axis ``s`` by
  ``curve/segments`` per segment (``curve_back/segments`` over the second half),
  plus a normal random term of ``curve_var/segments``; afterwards the heading
  is pulled towards +Y by tropism: ``d ← normalise(d + attract_up·Ŷ/segments)``.
* **Taper** — radius along the stem ``r(t) = r₀ (1 − taper·t)``, ``t ∈ [0, 1]``;
  trunks flare at the base by ``1 + flare·(1 − t)^6``.
* **Children** — placed at offsets ``t`` spread evenly over ``[start, 1]`` with
  jitter, in *whorls* of ``whorl`` children sharing one offset (1: a spiral; a
  spruce's tiers: 4–6).  Azimuth ``φ = 2π·j/whorl + m·rotate ± rotate_var`` for
  child ``j`` of node ``m`` (with ``whorl = 1``: the phyllotactic spiral
  ``φ_k = k·rotate``); the *down angle* (from the parent's axis) is
  ``down_angle ± down_angle_var`` (linearly blended to ``down_angle_tip``
  towards the parent's tip).  Heading: ``d = cos(θ)·t̂ + sin(θ)·(cos φ·ŝ + sin φ·b̂)``
  in the parent's frame.
* **Lengths** — children of a trunk: ``len = length·L_trunk·shape_ratio(shape, r)`` with
  ``r = (1 − t)/(1 − base_size)`` (1 at the crown's base, 0 at the top), using the
  paper's eight crown shapes; deeper levels: ``len = length·(L_parent − 0.6·t·L_parent)``.
* **Radii** — ``r_child = r_parent(t)·(len_child/len_parent)^ratio_power`` (never
  thicker than the parent there).
* **Leaves** — alpha-masked cards on the last level's stems, ``leaves`` per stem
  scaled by the stem's relative length.  Azimuth about the stem measured from
  its horizontal side ``ŝ = t̂ × Ŷ`` towards ``b̂ = ŝ × t̂`` (up):
  ``φ_k = k·leaf_rotate + (−1)^k·leaf_lift ± leaf_rotate_var`` (180 = all round;
  ``leaf_rotate = 180`` with a small variation puts leaflets in two ranks, a
  pinnate frond, lifted into a V by ``leaf_lift``).  The card's width axis
  ``ŵ ⟂ d̂`` blends the horizontal ``d̂ × Ŷ`` (weight ``leaf_face_up``) with a
  random roll and is signed so the face normal ``ŵ × d̂`` points up.  A card's width
  is ``leaf_scale·leaf_scale_x`` times ``1 ± leaf_scale_var`` (with the length) and
  ``1 ± leaf_scale_x_var`` (alone); a share ``leaf_mirror`` of the cards is mirrored
  across (``ŵ → −ŵ``: an asymmetric texture, such as the two ``blade`` blades, shows
  both ways round; the renderers still see the face up).
* **The individual** — the seed also draws, once per tree: height
  ``scale ± scale_var``, a crown width factor ``1 ± crown_var`` on the limbs'
  lengths, an offset ``± angle_var`` on every down angle, the crown base
  ``base_size ± base_size_var`` and a lean ``lean ± lean_var`` (one trunk), so
  ``"NAME@SEED"`` is another tree of the same kind
  (:func:`forest.library.individuals.individual`).
* **Bark** — ``bark_texture`` picks the tileable detail of
  :func:`forest.library.textures.bark_rgb` (furrowed, scaly, ringed, smooth, papery).
* **Cut cards** — ``leaf_cut = "outline"`` (the default) cuts every leaf,
  cluster and far card to a convex outline of its texture's alpha
  (:mod:`forest.library.outline`), so fewer rays hit transparent texels;
  ``"quad"`` keeps whole quads.

The result is a :class:`Skeleton` (stem polylines, radii, leaf frames) from which
:mod:`forest.library.lod` builds meshes at every level of detail.  Everything is
drawn from ``np.random.Generator(PCG64(SeedSequence([seed, TAG, level])))`` so the
same recipe and seed give the same tree, and each level has its own stream.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ConfigError

TAG = 0x7EE5  # RNG stream tag of the tree generator
SHAPES = (
    "conical",
    "spherical",
    "hemispherical",
    "cylindrical",
    "tapered_cylindrical",
    "flame",
    "inverse_conical",
    "tend_flame",
)

LEVEL_DEFAULTS: dict[str, Any] = {
    "length": 1.0,
    "length_var": 0.0,
    "segments": 8,
    "curve": 0.0,
    "curve_back": 0.0,
    "curve_var": 0.0,
    "branches": 0,
    "start": 0.0,
    "down_angle": 45.0,
    "down_angle_var": 10.0,
    "down_angle_tip": None,
    "rotate": 137.5,
    "rotate_var": 15.0,
    "whorl": 1,
    "sides": 6,
}
TREE_DEFAULTS: dict[str, Any] = {
    "shape": "conical",
    "scale": 10.0,
    "scale_var": 0.0,
    "base_size": 0.2,
    "ratio": 0.02,
    "ratio_power": 1.2,
    "taper": 0.9,
    "flare": 0.4,
    "trunks": 1,
    "trunk_splay": 0.0,
    "trunk_splay_var": 0.0,
    "trunk_spread": 0.0,
    "attract_up": 0.0,
    "lean": 0.0,
    "lean_var": 0.0,
    "crown_var": 0.0,
    "angle_var": 0.0,
    "base_size_var": 0.0,
    "leaves": 10,
    "leaf_scale": 0.15,
    "leaf_scale_x": 0.6,
    "leaf_scale_var": 0.15,
    "leaf_scale_x_var": 0.0,
    "leaf_mirror": 0.0,
    "leaf_down_angle": 50.0,
    "leaf_down_angle_var": 15.0,
    "leaf_rotate": 137.5,
    "leaf_rotate_var": 180.0,
    "leaf_lift": 0.0,
    "leaf_start": 0.2,
    "leaf_shape": "broad",
    "leaf_colour": [0.06, 0.16, 0.03],
    "bark_colour": [0.12, 0.08, 0.05],
    "bark_texture": "furrowed",
    "translucency": 0.3,
    # The leaf cuticle's rough specular lobe (forest.render.path.materials): weight s and GGX α; a broadleaf's
    # waxy cuticle after Bousquet et al. (2005), Remote Sens. Environ. 98: 201-211.
    "leaf_sheen": 0.7,
    "leaf_roughness": 0.35,
    "leaf_face_up": 0.5,
    "leaf_segments": 1,
    "leaf_bend": 0.0,
    "leaf_cut": "outline",
}
LEAF_CUTS = ("outline", "quad")


@dataclass
class Level:
    """The stems of one level, grown together."""

    points: np.ndarray  # (S, P, 3) float64 polylines
    tangents: np.ndarray  # (S, P, 3) unit headings
    radii: np.ndarray  # (S, P) radii in metres
    side: np.ndarray  # (S, 3) unit reference axis (ring frames)
    length: np.ndarray  # (S,) stem lengths
    sides: int  # ring resolution at the highest level of detail


@dataclass
class Skeleton:
    """A grown tree: stem levels plus leaf cards (centres of the card's base edge)."""

    levels: list[Level]
    leaf_base: np.ndarray  # (N, 3) where the card's stalk end sits
    leaf_dir: np.ndarray  # (N, 3) unit direction from stalk to tip
    leaf_width: np.ndarray  # (N, 3) unit direction across the card
    leaf_size: np.ndarray  # (N, 2) [length, width] in metres
    recipe: dict = field(default_factory=dict)


def _norm(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n < 1e-12, 1.0, n)


def _rotate(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rodrigues' rotation of vectors ``v`` about unit ``axis`` by ``angle`` (radians), batched."""
    c = np.cos(angle)[..., None]
    s = np.sin(angle)[..., None]
    return v * c + np.cross(axis, v) * s + axis * np.sum(axis * v, axis=-1, keepdims=True) * (1.0 - c)


def _perpendicular(t: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Unit vector ⟂ ``t`` closest to ``ref`` (Gram–Schmidt), falling back to X or Z."""
    p = ref - np.sum(ref * t, axis=-1, keepdims=True) * t
    bad = np.linalg.norm(p, axis=-1) < 1e-6
    if np.any(bad):
        alt = np.where(np.abs(t[..., :1]) < 0.9, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]))
        alt = alt - np.sum(alt * t, axis=-1, keepdims=True) * t
        p = np.where(bad[..., None], alt, p)
    return _norm(p)


def shape_ratio(shape: str, r: np.ndarray) -> np.ndarray:
    """Weber & Penn's crown envelope: relative branch length at relative height ``1 − r``."""
    r = np.clip(r, 0.0, 1.0)
    if shape == "conical":
        return 0.2 + 0.8 * r
    if shape == "spherical":
        return 0.2 + 0.8 * np.sin(np.pi * r)
    if shape == "hemispherical":
        return 0.2 + 0.8 * np.sin(0.5 * np.pi * r)
    if shape == "cylindrical":
        return np.ones_like(r)
    if shape == "tapered_cylindrical":
        return 0.5 + 0.5 * r
    if shape == "flame":
        return np.where(r <= 0.7, r / 0.7, (1.0 - r) / 0.3)
    if shape == "inverse_conical":
        return 1.0 - 0.8 * r
    if shape == "tend_flame":
        return np.where(r <= 0.7, 0.5 + 0.5 * r / 0.7, 0.5 + 0.5 * (1.0 - r) / 0.3)
    raise ValueError(shape)


def validate_recipe(recipe: dict, where: str = "recipe") -> dict:
    """Fill defaults and check a recipe; raise :class:`ConfigError` naming the bad field."""
    if not isinstance(recipe, dict):
        raise ConfigError(where, None, "recipe must be a table")
    tree: dict[str, Any] = dict(TREE_DEFAULTS)
    t_in = recipe.get("tree", {})
    unknown = sorted(set(t_in) - set(TREE_DEFAULTS))
    if unknown:
        raise ConfigError(
            where, f"tree.{unknown[0]}", f"unknown key (expected one of: {', '.join(sorted(TREE_DEFAULTS))})"
        )
    tree.update(t_in)
    if tree["shape"] not in SHAPES:
        raise ConfigError(where, "tree.shape", f"must be one of {', '.join(SHAPES)}, got {tree['shape']!r}")
    from .textures import SHAPES as LEAF_SHAPES

    if tree["leaf_shape"] not in LEAF_SHAPES:
        raise ConfigError(
            where, "tree.leaf_shape", f"must be one of {', '.join(LEAF_SHAPES)}, got {tree['leaf_shape']!r}"
        )
    from .textures import BARK_STYLES

    if tree["bark_texture"] not in BARK_STYLES:
        raise ConfigError(
            where, "tree.bark_texture", f"must be one of {', '.join(BARK_STYLES)}, got {tree['bark_texture']!r}"
        )
    if tree["leaf_cut"] not in LEAF_CUTS:
        raise ConfigError(where, "tree.leaf_cut", f"must be one of {', '.join(LEAF_CUTS)}, got {tree['leaf_cut']!r}")
    for key in ("lean", "lean_var", "angle_var", "leaf_lift", "leaf_rotate_var"):
        v = tree[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 <= v <= 180):
            raise ConfigError(where, f"tree.{key}", f"must be a number in [0, 180], got {v!r}")
    for key in ("crown_var", "base_size_var", "leaf_scale_x_var", "leaf_mirror"):
        v = tree[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 <= v <= 0.9):
            raise ConfigError(where, f"tree.{key}", f"must be a number in [0, 0.9], got {v!r}")
    for key in ("scale", "leaf_scale"):
        v = tree[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 < v < 200):
            raise ConfigError(where, f"tree.{key}", f"must be a number in (0, 200), got {v!r}")
    for key in ("leaf_colour", "bark_colour"):
        v = tree[key]
        if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and 0 <= x <= 1 for x in v)):
            raise ConfigError(where, f"tree.{key}", f"must be three numbers in [0, 1], got {v!r}")
    if not (0 <= tree["translucency"] <= 1):
        raise ConfigError(where, "tree.translucency", f"must be in [0, 1], got {tree['translucency']!r}")
    for key, lo in (("leaf_sheen", 0.0), ("leaf_roughness", 0.02)):
        v = tree[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= 1):
            raise ConfigError(where, f"tree.{key}", f"must be a number in [{lo}, 1], got {v!r}")
    if not isinstance(tree["leaf_segments"], int) or not 1 <= tree["leaf_segments"] <= 16:
        raise ConfigError(
            where, "tree.leaf_segments", f"must be a whole number in [1, 16], got {tree['leaf_segments']!r}"
        )
    if not isinstance(tree["trunks"], int) or not 1 <= tree["trunks"] <= 200:
        raise ConfigError(where, "tree.trunks", f"must be a whole number in [1, 200], got {tree['trunks']!r}")
    levels_in = recipe.get("level", [])
    if not isinstance(levels_in, list) or not levels_in or len(levels_in) > 5:
        raise ConfigError(where, "level", "must be 1 to 5 [[level]] tables")
    levels: list[dict[str, Any]] = []
    for i, lv in enumerate(levels_in):
        unknown = sorted(set(lv) - set(LEVEL_DEFAULTS))
        if unknown:
            raise ConfigError(
                where, f"level[{i}].{unknown[0]}", f"unknown key (expected one of: {', '.join(sorted(LEVEL_DEFAULTS))})"
            )
        d = dict(LEVEL_DEFAULTS)
        d.update(lv)
        if not isinstance(d["segments"], int) or not 1 <= d["segments"] <= 64:
            raise ConfigError(
                where, f"level[{i}].segments", f"must be a whole number in [1, 64], got {d['segments']!r}"
            )
        if not isinstance(d["branches"], int) or not 0 <= d["branches"] <= 2000:
            raise ConfigError(
                where, f"level[{i}].branches", f"must be a whole number in [0, 2000], got {d['branches']!r}"
            )
        if isinstance(d["whorl"], bool) or not isinstance(d["whorl"], int) or not 1 <= d["whorl"] <= 64:
            raise ConfigError(where, f"level[{i}].whorl", f"must be a whole number in [1, 64], got {d['whorl']!r}")
        if not isinstance(d["sides"], int) or not 3 <= d["sides"] <= 64:
            raise ConfigError(where, f"level[{i}].sides", f"must be a whole number in [3, 64], got {d['sides']!r}")
        levels.append(d)
    return {"tree": tree, "level": levels, "lod_tone": _lod_tone(recipe.get("lod_tone", {}), where)}


#: What a recipe's ``[lod_tone]`` may name: the lower levels of detail (the high level is the reference) and
#: ``far_top``, the far level's horizontal card (``far`` tones its vertical cards).
TONED_LEVELS = ("medium", "low", "far", "far_top")


def _lod_tone(table: Any, where: str) -> dict[str, dict[str, Any]]:
    """``[lod_tone]``: per lower level, the factor on its leaves' albedo (RGB) and on their sheen's weight
    (``far`` the far level's vertical cards, ``far_top`` its horizontal card, seen from above).

    The lower levels keep the high level's coverage by construction (:mod:`forest.library.build`) but not its
    tone: a crown of fewer, larger cluster cards, or three crossed cards, lets more of the sky and sun reach
    the surface a camera sees than thousands of leaves shading each other, and a flat card shows a broad
    sheen where leaves facing every way show glints.  The factors are fitted in a forest, not on one tree,
    by ``bench/bench_lod_tone.py --fit``; 1 (the default) keeps the level as built.
    """
    if not isinstance(table, dict):
        raise ConfigError(where, "lod_tone", "must be a table of levels (medium, low, far, far_top)")
    unknown = sorted(set(table) - set(TONED_LEVELS))
    if unknown:
        raise ConfigError(
            where, f"lod_tone.{unknown[0]}", f"unknown level (expected one of: {', '.join(TONED_LEVELS)})"
        )
    out: dict[str, dict[str, Any]] = {}
    for level in TONED_LEVELS:
        entry = table.get(level, table.get("far", {}) if level == "far_top" else {})  # the top card: as `far`
        if not isinstance(entry, dict) or set(entry) - {"albedo", "sheen"}:
            raise ConfigError(where, f"lod_tone.{level}", "must be a table with `albedo` (three numbers) and `sheen`")
        albedo = entry.get("albedo", [1.0, 1.0, 1.0])
        if not (
            isinstance(albedo, list)
            and len(albedo) == 3
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and 0 < x <= 4 for x in albedo)
        ):
            raise ConfigError(where, f"lod_tone.{level}.albedo", f"must be three numbers in (0, 4], got {albedo!r}")
        sheen = entry.get("sheen", 1.0)
        if isinstance(sheen, bool) or not isinstance(sheen, (int, float)) or not 0 <= sheen <= 4:
            raise ConfigError(where, f"lod_tone.{level}.sheen", f"must be a number in [0, 4], got {sheen!r}")
        out[level] = {"albedo": [float(x) for x in albedo], "sheen": float(sheen)}
    return out


def _grow(origins, headings, sides_vec, lengths, radii0, lv: dict, tree: dict, level: int, rng) -> Level:
    """Grow ``S`` stems of one level as curved polylines (see module docstring)."""
    S = len(origins)
    n = lv["segments"]
    pts = np.zeros((S, n + 1, 3))
    tan = np.zeros((S, n + 1, 3))
    pts[:, 0] = origins
    d = headings.copy()
    tan[:, 0] = d
    seg_len = lengths / n
    curve = np.radians(lv["curve"]) / n
    back = np.radians(lv["curve_back"]) / n
    var = np.radians(lv["curve_var"]) / n
    up = np.array([0.0, 1.0, 0.0])
    noise = rng.standard_normal((S, n))
    for j in range(n):
        pts[:, j + 1] = pts[:, j] + d * seg_len[:, None]
        ang = (curve if (lv["curve_back"] == 0 or j < n / 2) else back) + var * noise[:, j]
        axis = _perpendicular(d, sides_vec)
        d = _norm(_rotate(d, axis, np.full(S, 1.0) * ang))
        if tree["attract_up"] and level > 0:
            d = _norm(d + tree["attract_up"] * up / n)
        tan[:, j + 1] = d
    t = np.linspace(0.0, 1.0, n + 1)
    radii = radii0[:, None] * (1.0 - tree["taper"] * t)[None, :]
    if level == 0:
        radii = radii * (1.0 + tree["flare"] * (1.0 - t) ** 6)[None, :]
    return Level(pts, tan, radii, _perpendicular(headings, sides_vec), lengths.astype(np.float64), lv["sides"])


def _sample_along(level: Level, stem: np.ndarray, t: np.ndarray):
    """Position, heading, radius and side frame of ``level``'s stems at offsets ``t ∈ [0, 1]``."""
    P = level.points.shape[1]
    x = t * (P - 1)
    i0 = np.clip(np.floor(x).astype(np.int64), 0, P - 2)
    f = (x - i0)[:, None]
    pos = level.points[stem, i0] * (1 - f) + level.points[stem, i0 + 1] * f
    tan = _norm(level.tangents[stem, i0] * (1 - f) + level.tangents[stem, i0 + 1] * f)
    rad = level.radii[stem, i0] * (1 - f[:, 0]) + level.radii[stem, i0 + 1] * f[:, 0]
    side = _perpendicular(tan, level.side[stem])
    return pos, tan, rad, side


def _children_offsets(counts: np.ndarray, start: np.ndarray, rng, whorl: int = 1):
    """Stem index, offset ``t``, index and whorl slot of every child on its parent.

    Children are grouped into *nodes* of ``whorl`` (1: one child a node, a spiral);
    the nodes of a parent spread evenly over ``[start, 1]`` with jitter,
    ``t = s + (1 − s)(m + ½ + 0.35·U)/M`` for node ``m`` of ``M``, and every
    child of a node shares its ``t``.  Returns ``(stem, t, k, m, j)`` with
    ``k`` the child's index on its parent, ``m = k // whorl`` and ``j = k mod whorl``.
    """
    total = int(counts.sum())
    w = max(1, int(whorl))
    stem = np.repeat(np.arange(len(counts)), counts)
    k = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)  # index within its parent
    m, j = k // w, k % w
    nodes = np.repeat(-(-counts // w), counts).astype(np.float64)
    s0 = np.repeat(start, counts)
    jitter = rng.uniform(-1, 1, total)
    jitter = jitter[np.arange(total) - j]  # one draw a node: its first child's
    t = s0 + (1.0 - s0) * (m + 0.5 + 0.35 * jitter) / nodes
    return stem, np.clip(t, 0.0, 1.0), k, m, j


def _horizontal_frame(tan: np.ndarray, fallback: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(ŝ, b̂)`` ⟂ the heading: ``ŝ = t̂ × Ŷ`` horizontal, ``b̂ = ŝ × t̂`` towards +Y (``fallback`` when vertical)."""
    up = np.array([0.0, 1.0, 0.0])
    s = np.cross(tan, up)
    ok = np.linalg.norm(s, axis=-1, keepdims=True) > 1e-6
    s = np.where(ok, s, fallback)
    s = _perpendicular(tan, s)
    return s, _norm(np.cross(s, tan))


def grow(recipe: dict, seed: int) -> Skeleton:
    """Grow the tree described by a validated ``recipe`` with ``seed``.

    The seed also draws the *individual*: height ``scale ± scale_var``, crown
    width factor ``1 ± crown_var`` (on the limbs' lengths), a branch-angle offset
    ``± angle_var`` degrees (on every branching level's down angles), crown base
    ``base_size ± base_size_var`` and lean ``lean ± lean_var`` degrees (single trunks).
    """
    tree = recipe["tree"]
    levels_cfg = recipe["level"]

    def rng_for(tag: int):
        return np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, TAG, tag])))

    rng = rng_for(100)
    nt = int(tree["trunks"])
    scale = max(0.05, tree["scale"] + tree["scale_var"] * rng.uniform(-1, 1))
    lv0 = levels_cfg[0]
    len0 = scale * lv0["length"] * (1.0 + lv0["length_var"] * rng.uniform(-1, 1, nt))
    az = np.radians(137.508) * np.arange(nt) + rng.uniform(0, 2 * np.pi)
    tilt = np.radians(tree["trunk_splay"] + tree["trunk_splay_var"] * rng.uniform(-1, 1, nt)) * (
        nt > 1 or tree["trunk_splay"] > 0
    )
    # The individual: crown width, branch angles, crown base and lean (one draw each).
    crown = max(0.2, 1.0 + tree["crown_var"] * rng.uniform(-1, 1))
    angle_offset = tree["angle_var"] * rng.uniform(-1, 1)
    base_size = float(np.clip(tree["base_size"] + tree["base_size_var"] * rng.uniform(-1, 1), 0.0, 0.98))
    lean = np.radians(tree["lean"] + tree["lean_var"] * rng.uniform(-1, 1))
    if nt == 1:
        tilt = tilt + lean
    head = np.stack([np.sin(tilt) * np.cos(az), np.cos(tilt), np.sin(tilt) * np.sin(az)], axis=1)
    spread = tree["trunk_spread"] * np.sqrt(rng.uniform(0, 1, nt))
    origins = np.stack([spread * np.cos(az), np.zeros(nt), spread * np.sin(az)], axis=1)
    side0 = np.stack([-np.sin(az), np.zeros(nt), np.cos(az)], axis=1)
    radii0 = len0 * tree["ratio"]
    levels = [_grow(origins, head, side0, len0, radii0, lv0, tree, 0, rng_for(0))]

    for L in range(1, len(levels_cfg)):
        parent = levels[-1]
        pcfg = levels_cfg[L - 1]
        lv = levels_cfg[L]
        rng = rng_for(L)
        rel = parent.length / parent.length.max()
        if L == 1:
            counts = np.full(len(parent.length), pcfg["branches"], dtype=np.int64)
            start = np.full(len(parent.length), base_size)
        else:
            counts = np.round(pcfg["branches"] * (0.3 + 0.7 * rel)).astype(np.int64)
            start = np.full(len(parent.length), pcfg["start"])
        if counts.sum() == 0:
            break
        stem, t, k, m, j = _children_offsets(counts, start, rng, lv["whorl"])
        pos, ptan, prad, pside = _sample_along(parent, stem, t)
        pbin = _norm(np.cross(ptan, pside))
        w = max(1, int(lv["whorl"]))
        phi = (
            2.0 * np.pi * j / w
            + np.radians(m * lv["rotate"] + lv["rotate_var"] * rng.uniform(-1, 1, len(t)))
            + rng.uniform(0, 2 * np.pi, len(counts))[stem]
        )
        down, tip_angle = lv["down_angle"], lv["down_angle"] if lv["down_angle_tip"] is None else lv["down_angle_tip"]
        span = (t - start[stem]) / np.maximum(1.0 - start[stem], 1e-6)
        theta = np.radians(
            down * (1 - span) + tip_angle * span + angle_offset + lv["down_angle_var"] * rng.uniform(-1, 1, len(t))
        )
        radial = np.cos(phi)[:, None] * pside + np.sin(phi)[:, None] * pbin
        head = _norm(np.cos(theta)[:, None] * ptan + np.sin(theta)[:, None] * radial)
        plen = parent.length[stem]
        if L == 1:
            r = (1.0 - t) / max(1.0 - base_size, 1e-6)
            clen = crown * lv["length"] * plen * shape_ratio(tree["shape"], r)
        else:
            clen = lv["length"] * (plen - 0.6 * t * plen)
        clen = clen * (1.0 + lv["length_var"] * rng.uniform(-1, 1, len(t)))
        clen = np.maximum(clen, 1e-3)
        crad = np.minimum(prad * (clen / plen) ** tree["ratio_power"], prad * 0.95)
        side = _perpendicular(head, np.cross(head, ptan))
        levels.append(_grow(pos, head, side, clen, crad, lv, tree, L, rng))

    # Leaves on the last grown level.
    rng = rng_for(99)
    last = levels[-1]
    rel = last.length / last.length.max()
    counts = np.round(tree["leaves"] * (0.3 + 0.7 * rel)).astype(np.int64)
    leaf_start = np.full(len(counts), tree["leaf_start"])
    stem, t, k, _, _ = _children_offsets(counts, leaf_start, rng)
    pos, ptan, prad, pside = _sample_along(last, stem, t)
    # Azimuth about the stem from its horizontal side ŝ towards b̂ (up): alternate
    # leaves (rotate 180°) lie left and right, lifted by ±leaf_lift into a V.
    hs, hb = _horizontal_frame(ptan, pside)
    sign = np.where(k % 2 == 0, 1.0, -1.0)
    phi = np.radians(
        k * tree["leaf_rotate"] + sign * tree["leaf_lift"] + tree["leaf_rotate_var"] * rng.uniform(-1, 1, len(t))
    )
    theta = np.radians(tree["leaf_down_angle"] + tree["leaf_down_angle_var"] * rng.uniform(-1, 1, len(t)))
    radial = np.cos(phi)[:, None] * hs + np.sin(phi)[:, None] * hb
    ldir = _norm(np.cos(theta)[:, None] * ptan + np.sin(theta)[:, None] * radial)
    # Card width axis ŵ ⟂ d̂: the horizontal ``d̂ × Ŷ`` (card facing up) blended with a
    # random roll by ``1 − leaf_face_up``; then signed so the face normal ŵ × d̂ points up.
    up = np.array([0.0, 1.0, 0.0])
    w_flat = _perpendicular(ldir, np.cross(ldir, up) + 1e-6 * hs)
    roll = rng.uniform(0, 2 * np.pi, len(t))
    w_ref, w_ref2 = _perpendicular(ldir, hs), _norm(np.cross(ldir, _perpendicular(ldir, hs)))
    w_rand = np.cos(roll)[:, None] * w_ref + np.sin(roll)[:, None] * w_ref2
    w_rand = w_rand * np.where(np.sum(w_rand * w_flat, axis=1, keepdims=True) < 0, -1.0, 1.0)
    fu = tree["leaf_face_up"]
    width_axis = _perpendicular(ldir, fu * w_flat + (1 - fu) * w_rand)
    face = np.cross(width_axis, ldir)
    width_axis = np.where(face[:, 1:2] < 0, -width_axis, width_axis)
    size = tree["leaf_scale"] * (1.0 + tree["leaf_scale_var"] * rng.uniform(-1, 1, len(t)))
    lsize = np.stack([size, size * tree["leaf_scale_x"]], axis=1)
    if tree["leaf_scale_x_var"] or tree["leaf_mirror"]:
        # Their own stream, so recipes without them keep every leaf they had.
        vary = rng_for(98)
        lsize[:, 1] *= 1.0 + tree["leaf_scale_x_var"] * vary.uniform(-1, 1, len(t))
        mirror = vary.random(len(t)) < tree["leaf_mirror"]
        width_axis = np.where(mirror[:, None], -width_axis, width_axis)
    base = pos + ldir * prad[:, None]
    return Skeleton(levels, base, ldir, width_axis, lsize, recipe)
