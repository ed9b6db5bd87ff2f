"""Levels of detail: meshes at triangle budgets, leaf-cluster cards and far impostors.

* **Bark** — each stem is a tube: rings of ``sides`` vertices around the
  polyline, ring ``j`` at ``p_j + r_j (cos α · n̂₁ + sin α · n̂₂)`` with ``n̂₁, n̂₂``
  a frame ⟂ the heading; ``2·sides·segments`` triangles a stem.  Lower levels
  of detail use fewer sides, fewer rings (a subset of the polyline's points, so
  the skeleton and its bounds stay) and drop the thinnest levels first.
* **Leaves** — the high level has one card per leaf.  Lower levels keep a
  random subset of ``m`` of the ``N`` leaves and draw each as a *cluster card*
  (a texture holding several leaves) scaled about its centre so the projected
  leaf area is preserved: ``m · A_card · c_cluster = N · A_leaf · c_leaf``, with
  ``c`` the texture's alpha coverage.  Equal area spread over the same volume
  keeps the crown's alpha coverage and colour (checked on rendered previews).
* **Far** — three vertical cards crossed at 60° through the trunk axis, each
  textured with an orthographic impostor of the high level seen along the
  card's normal (a z-buffered splat of area-weighted surface samples; with ``a``
  the covered share of a pixel's 4×4 sub-pixels, the card's alpha is
  ``1 − (1 − a)^γ`` where ``γ`` is chosen so the stacked cards cover as much as
  the high level does, :func:`calibrate_opacity`).  Six triangles.  The far form
  is one tinted leaf part: its texture holds bark and leaves alike.

UV convention (Mitsuba's): ``v = 0`` is the image's first (top) row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .generator import Level, Skeleton, _norm, _perpendicular
from .mesh import MeshData
from .outline import Outline, clip_polygon, quad

LODS = ("high", "medium", "low", "far")
BUDGETS = {"high": (50_000, 200_000), "medium": (5_000, 20_000), "low": (500, 2_000), "far": (2, 64)}
TARGETS = {"high": 180_000, "medium": 12_000, "low": 1_500}
BARK_SHARE = {"high": 1.0, "medium": 0.4, "low": 0.35}
TAG_LOD = 0x10D
#: The tree presets' high level stays within this many triangles; cut cards add triangles only below it.
HIGH_MAX = 70_000
#: Most triangles a cut card may take per strip, per level (the quad takes 2).
MAX_CARD_TRIANGLES = {"high": 4, "medium": 4, "low": 4, "far": 4}
#: Cost of a card's triangles relative to the quad's, as a power (see :func:`pick_outline`): log 1.1 / log 1.5.
TRIANGLE_EXPONENT = math.log(1.1) / math.log(1.5)


def stem_v(level: Level) -> np.ndarray:
    """Bark ``v`` at every point of ``level``'s polylines: ``v(s) = ∫₀ˢ ds′ / (2π r(s′))``.

    One texture tile up the stem per circumference, so with ``u = α/2π`` once
    around a texel stays square however the stem tapers (the bark's furrows
    converge as the stem thins, as they do on a tree).  Trapezoid rule on
    ``1/r`` over the polyline; computed on the full polyline so that every level
    of detail, which keeps a subset of its points, maps the bark identically.
    """
    seg = np.linalg.norm(np.diff(level.points, axis=1), axis=2)
    inv = 1.0 / (2.0 * np.pi * np.maximum(level.radii, 1e-4))
    dv = seg * 0.5 * (inv[:, 1:] + inv[:, :-1])
    return np.concatenate([np.zeros((len(seg), 1)), np.cumsum(dv, axis=1)], axis=1)


def tubes(level: Level, sides: int, rows: np.ndarray) -> MeshData:
    """Tubes around ``level``'s polylines using the points ``rows`` and ``sides`` per ring.

    Ring vertex ``k`` at ``p + r(cos α_k n̂₁ + sin α_k n̂₂)`` with ``α_k = 2πk/sides``
    and ``n̂₂ = t̂ × n̂₁``, so going around the ring turns counter-clockwise seen
    from the stem's tip and the faces ``(j,k) (j,k+1) (j+1,k+1)`` face outward:
    the winding's normal agrees with the stored radial normals.
    UV: ``u = α/2π`` around (a seam column duplicates ``u = 1``), ``v`` from
    :func:`stem_v`, so the bark texture tiles along the stem.
    """
    pts = level.points[:, rows]
    tan = level.tangents[:, rows]
    rad = level.radii[:, rows]
    S, R = rad.shape
    K = sides
    n1 = _perpendicular(tan, level.side[:, None, :].repeat(R, axis=1))
    n2 = _norm(np.cross(tan, n1))
    a = np.linspace(0.0, 2.0 * np.pi, K + 1)
    ca, sa = np.cos(a), np.sin(a)
    nrm = ca[None, None, :, None] * n1[:, :, None, :] + sa[None, None, :, None] * n2[:, :, None, :]
    pos = pts[:, :, None, :] + rad[:, :, None, None] * nrm
    v = stem_v(level)[:, rows]
    uv = np.stack(
        np.broadcast_arrays(np.broadcast_to((a / (2 * np.pi))[None, None, :], (S, R, K + 1)), v[:, :, None]), axis=-1
    )
    # Faces: quad (j, k) → (j,k) (j,k+1) (j+1,k+1) and (j,k) (j+1,k+1) (j+1,k); winding outward.
    j, k = np.meshgrid(np.arange(R - 1), np.arange(K), indexing="ij")
    i00 = j * (K + 1) + k
    i10 = (j + 1) * (K + 1) + k
    i11 = (j + 1) * (K + 1) + k + 1
    i01 = j * (K + 1) + k + 1
    tmpl = np.concatenate([np.stack([i00, i01, i11], -1).reshape(-1, 3), np.stack([i00, i11, i10], -1).reshape(-1, 3)])
    faces = (tmpl[None, :, :] + (np.arange(S) * R * (K + 1))[:, None, None]).reshape(-1, 3)
    return MeshData(
        pos.reshape(-1, 3).astype(np.float32),
        faces.astype(np.uint32),
        nrm.reshape(-1, 3).astype(np.float32),
        uv.reshape(-1, 2).astype(np.float32),
    )


@dataclass(frozen=True)
class CardTemplate:
    """One card's triangles in uv, shared by every card of a part.

    ``uv (V, 2)`` the vertices, ``band (V,)`` the strip along the card each
    belongs to (0 for a flat card; ``K`` strips split ``v`` at ``j/K``) and
    ``faces (F, 3)`` counter-clockwise in (u, v), so on the card they wind about
    ``ŵ × d̂`` (u runs along ŵ, v along d̂).
    """

    uv: np.ndarray
    band: np.ndarray
    faces: np.ndarray

    @property
    def triangles(self) -> int:
        """Triangles of one card."""
        return len(self.faces)


def card_template(outline: Outline | None = None, segments: int = 1) -> CardTemplate:
    """The card's outline (default: the whole quad) cut into ``segments`` strips along ``v``.

    Each strip ``v ∈ [j/K, (j+1)/K]`` holds the convex piece ``outline ∩ strip``
    (Sutherland–Hodgman), triangulated as a fan; pieces share their vertices on
    the strip boundaries, so a bent card stays one connected sheet.  The quad gives the two triangles
    per strip of :func:`cards` / :func:`bent_cards`.
    """
    poly = (outline or quad()).uv
    K = max(1, int(segments))
    uvs, bands, faces = [], [], []
    count = 0
    for j in range(K):
        piece = poly
        if K > 1:
            piece = clip_polygon(clip_polygon(poly, 1, j / K, True), 1, (j + 1) / K, False)
        if len(piece) < 3:
            continue
        k = np.arange(1, len(piece) - 1)
        faces.append(np.stack([np.zeros_like(k), k, k + 1], axis=1) + count)
        uvs.append(piece)
        bands.append(np.full(len(piece), j))
        count += len(piece)
    uv, band, f = np.concatenate(uvs), np.concatenate(bands), np.concatenate(faces).astype(np.int64)
    # Pieces of neighbouring strips share their vertices on the boundary (one card, one connected mesh).
    _, first, inverse = np.unique(np.round(uv, 9), axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    remap = np.empty(len(order), np.int64)
    remap[order] = np.arange(len(order))
    keep = first[order]
    return CardTemplate(uv[keep], band[keep], remap[inverse.ravel()][f])


def _place(template: CardTemplate, pos: np.ndarray, nrm: np.ndarray, flip: np.ndarray) -> MeshData:
    """Per-card vertices ``pos (n, V, 3)`` and normals ``nrm (n, V, 3)`` with the template's faces.

    Cards whose normal was flipped to face up (``flip``) take the faces in reverse order, so every
    triangle winds counter-clockwise about its stored normal.
    """
    n, V = pos.shape[:2]
    f = template.faces
    tmpl = np.where(flip[:, None, None], f[None, :, [0, 2, 1]], f[None])
    faces = (tmpl + V * np.arange(n)[:, None, None]).reshape(-1, 3)
    uv = np.broadcast_to(template.uv[None], (n, V, 2))
    return MeshData(
        pos.reshape(-1, 3).astype(np.float32),
        faces.astype(np.uint32),
        nrm.reshape(-1, 3).astype(np.float32),
        uv.reshape(-1, 2).astype(np.float32),
    )


def cards(
    base: np.ndarray,
    direction: np.ndarray,
    width: np.ndarray,
    size: np.ndarray,
    scale: float = 1.0,
    outline: Outline | None = None,
) -> MeshData:
    """Cards of ``size = [length, width]`` from ``base`` along ``direction``, cut to ``outline``, scaled about their centre.

    The card's point at ``(u, v)`` is ``c + s·((v − ½)·len·d̂ + (u − ½)·wid·ŵ)`` with
    ``c = base + ½·len·d̂``: u across, v from stalk (0) to tip (1); without an
    outline the card is the quad ``(0,0) (1,0) (1,1) (0,1)``.  Normals are
    ``ŵ × d̂`` flipped to face up (+Y).  The outline's fan is wound
    counter-clockwise about ``ŵ × d̂`` (``(p₁ − p₀) × (p₂ − p₀)`` along it): a
    flipped card gets the reversed order.
    """
    t = card_template(outline)
    c = base + 0.5 * size[:, :1] * direction
    hl = scale * size[:, :1] * direction
    hw = scale * size[:, 1:] * width
    u, v = t.uv[:, 0], t.uv[:, 1]
    pos = c[:, None, :] + (v - 0.5)[None, :, None] * hl[:, None, :] + (u - 0.5)[None, :, None] * hw[:, None, :]
    nrm = _norm(np.cross(width, direction))  # the winding's normal of the outline's fan
    flip = nrm[:, 1] < 0
    nrm = np.where(flip[:, None], -nrm, nrm)
    return _place(t, pos, np.repeat(nrm[:, None, :], len(u), axis=1), flip)


def bent_cards(
    base: np.ndarray,
    direction: np.ndarray,
    width: np.ndarray,
    size: np.ndarray,
    segments: int,
    bend: float,
    outline: Outline | None = None,
) -> MeshData:
    """Cards split into ``segments`` strips along their length, drooping by ``bend`` degrees, cut to ``outline``.

    The centreline heading at arc parameter ``s ∈ [0, 1]`` is ``d̂`` rotated
    towards −Y about ``ŵ`` by ``bend·s``; points are the running sum of headings
    times ``len/segments``.  Strip ``j`` is flat: its point at ``(u, v)`` is
    ``m_j + (v·K − j)·(m_{j+1} − m_j) + (u − ½)·wid·ŵ`` (``m`` the centreline),
    and the normal blends the strip's end normals.  The quad gives
    ``2·segments`` triangles a card; an outline gives its pieces per strip
    (:func:`card_template`).
    """
    if segments <= 1 and bend == 0:
        return cards(base, direction, width, size, outline=outline)
    n = len(base)
    K = segments
    s = np.linspace(0.0, 1.0, K + 1)
    down = np.array([0.0, -1.0, 0.0])
    # Bend axis: ŵ oriented so that positive rotation turns d̂ towards −Y.
    axis = width * np.sign(np.sum(np.cross(width, direction) * down, axis=1, keepdims=True) + 1e-12)
    from .generator import _rotate

    heads = np.stack([_rotate(direction, axis, np.full(n, np.radians(bend) * si)) for si in s[:-1]], axis=1)
    steps = heads * (size[:, :1, None] / K)
    centre = np.concatenate([base[:, None, :], base[:, None, :] + np.cumsum(steps, axis=1)], axis=1)
    tangent = np.concatenate([heads, heads[:, -1:]], axis=1)
    # Row normals: ŵ × t̂, the winding's normal of a strip before flipping.
    nrm = _norm(np.cross(np.broadcast_to(width[:, None, :], tangent.shape), tangent))
    flip = nrm[:, K // 2, 1] < 0
    nrm = np.where(flip[:, None, None], -nrm, nrm)
    t = card_template(outline, K)
    j = t.band
    f = np.clip(t.uv[:, 1] * K - j, 0.0, 1.0)
    hw = size[:, 1:] * width
    pos = (
        centre[:, j]
        + f[None, :, None] * (centre[:, j + 1] - centre[:, j])
        + (t.uv[:, 0] - 0.5)[None, :, None] * hw[:, None]
    )
    vn = _norm((1.0 - f)[None, :, None] * nrm[:, j] + f[None, :, None] * nrm[:, j + 1])
    return _place(t, pos, vn, flip)


def _tube_plan(sk: Skeleton, lod: str, budget: float) -> list[tuple[int, int, np.ndarray]]:
    """Choose (level index, sides, ring rows) per level for ``lod`` within ``budget`` bark triangles."""
    plan = []
    used = 0
    for i, lv in enumerate(sk.levels):
        P = lv.points.shape[1]
        n = P - 1
        if lod == "high":
            sides, segs = lv.sides, n
        elif lod == "medium":
            sides, segs = max(3, (lv.sides + 1) // 2), max(1 if i else 2, math.ceil(n / 2))
        else:
            sides, segs = max(3, lv.sides // 3 + (1 if i == 0 else 0)), max(1 if i else 2, math.ceil(n / 4))
        rows = np.unique(np.round(np.linspace(0, n, segs + 1)).astype(np.int64))
        cost = 2 * sides * (len(rows) - 1) * lv.points.shape[0]
        if i == 0 and cost > budget and lod != "high":
            # Many thin stems (a grass clump): the coarsest tubes, or none at all.
            sides, rows = 3, np.array([0, n])
            cost = 6 * lv.points.shape[0]
            if cost > budget:
                break
        if i > 0 and used + cost > budget:
            break
        plan.append((i, sides, rows))
        used += cost
    return plan


def bark_mesh(sk: Skeleton, lod: str, budget: float) -> MeshData:
    """The bark of skeleton ``sk`` at level ``lod``: its levels' tubes, merged, within about ``budget`` triangles."""
    from .mesh import merge_meshes

    return merge_meshes([tubes(sk.levels[i], sides, rows) for i, sides, rows in _tube_plan(sk, lod, budget)])


def pick_outline(options: dict[int, Outline], segments: int = 1, cards: int = 0, budget: int | None = None) -> Outline:
    """The outline a level cuts its cards to: least ``area · (tris / quad_tris)^TRIANGLE_EXPONENT``.

    ``options`` maps a triangle count to the best outline with at most that many
    (:func:`forest.library.outline.card_outlines`); ``tris`` is the card's
    triangles (:func:`card_template` with ``segments`` strips) and
    ``quad_tris = 2·segments`` the quad's.  The area is the share of the quad a
    ray can hit, so it is what the transparent hits scale with; the exponent
    makes a third triangle on a flat card buy at least 10 % less area
    (``1.5^0.235 = 1.1``).  With ``budget``, only outlines whose ``cards`` cards
    fit in it are considered (the quad always is).
    """
    best, best_score = quad(), float("inf")
    for o in [quad()] + [options[t] for t in sorted(options)]:
        tris = card_template(o, segments).triangles
        if budget is not None and o.triangles > 2 and cards * tris > budget:
            continue
        score = o.area * (tris / (2.0 * segments)) ** TRIANGLE_EXPONENT
        if score < best_score - 1e-9:
            best, best_score = o, score
    return best


def leaf_meshes(
    sk: Skeleton,
    lod: str,
    budget: int,
    seed: int,
    cov_leaf: float,
    cov_cluster: float,
    cover: float = 1.0,
    outline: Outline | None = None,
) -> tuple[MeshData, bool]:
    """Leaf cards for ``lod`` cut to ``outline``: every leaf at the high level, an area-preserving subset below.

    ``budget`` is in triangles.  At the high level ``outline`` is the single
    leaf's; below, the cluster texture's, and the level keeps as many cards as
    fit the budget.  ``cover`` multiplies the cluster cards' scale beyond the
    area-preserving one (the build matches the rendered coverage with it:
    clumped foliage overlaps more within a clump than the fewer, larger cluster
    cards do).  The coverages ``cov_*`` are the textures' mean alpha over the
    whole card, so an outline (which holds all of the alpha) changes no area.
    Returns the mesh and whether it uses the cluster texture.
    """
    N = len(sk.leaf_base)
    tree = sk.recipe["tree"]
    segments = tree["leaf_segments"]
    if lod == "high" and N * card_template(outline, segments).triangles <= budget:
        return bent_cards(
            sk.leaf_base, sk.leaf_dir, sk.leaf_width, sk.leaf_size, segments, tree["leaf_bend"], outline
        ), False
    per_card = card_template(outline).triangles
    m = max(1, min(N, budget // per_card))
    rng = np.random.Generator(
        np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, TAG_LOD, LODS.index(lod)]))
    )
    keep = np.sort(rng.permutation(N)[:m])
    if lod == "high":
        # Too many leaves for the budget: fewer single-leaf cards, same total area.
        return cards(
            sk.leaf_base[keep],
            sk.leaf_dir[keep],
            sk.leaf_width[keep],
            sk.leaf_size[keep],
            scale=math.sqrt(N / m),
            outline=outline,
        ), False
    area_leaf = float(np.sum(sk.leaf_size[:, 0] * sk.leaf_size[:, 1])) * cov_leaf
    area_kept = float(np.sum(sk.leaf_size[keep, 0] * sk.leaf_size[keep, 1])) * cov_cluster
    s = cover * math.sqrt(area_leaf / max(area_kept, 1e-12))
    return cards(
        sk.leaf_base[keep], sk.leaf_dir[keep], sk.leaf_width[keep], sk.leaf_size[keep], scale=s, outline=outline
    ), True


# ---------------------------------------------------------------------------
# Far impostor
# ---------------------------------------------------------------------------

FAR_VIEWS = 3
#: The far atlas's tiles: the ``FAR_VIEWS`` vertical cards', then the horizontal card's (the view from above).
FAR_TILES = FAR_VIEWS + 1
MAX_SAMPLES = 2_500_000


def _sample_surface(mesh: MeshData, density: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted random points on ``mesh``: ``ceil(area·density)`` per triangle (≥ 1).

    Barycentrics ``(1−√r₁, √r₁(1−r₂), √r₁ r₂)`` are uniform over a triangle
    (Osada et al. 2002).  Returns positions and interpolated uv.
    """
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces.astype(np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    cnt = np.minimum(np.ceil(area * density).astype(np.int64), 4096)
    cnt = np.maximum(cnt, 1)
    tri = np.repeat(np.arange(len(f)), cnt)
    r1 = np.sqrt(rng.uniform(0, 1, len(tri)))
    r2 = rng.uniform(0, 1, len(tri))
    w = np.stack([1 - r1, r1 * (1 - r2), r1 * r2], axis=1)
    ft = f[tri]
    pos = (v[ft] * w[:, :, None]).sum(axis=1)
    uv = (mesh.uv.astype(np.float64)[ft] * w[:, :, None]).sum(axis=1)
    return pos, uv


def card_coverage(alpha: np.ndarray) -> np.ndarray:
    """Mean coverage of the crossed cards seen along each card's normal, orthographically.

    ``alpha (K, H, W)`` is card ``k``'s opacity over its width ``s ∈ [−R, R]``
    (column ``j`` ↔ ``s = −R + (j + ½)·2R/W``).  Seen from view ``j`` (direction
    ``d = −n̂_j``, lateral axis ``ê_j``), the ray at lateral offset ``a`` meets card
    ``k`` at ``t = −a (ê_j·n̂_k)/(d·n̂_k)``, i.e. at card coordinate
    ``s = a (ê_j·û_k) + t (d·û_k)``; the cards compose as ``1 − Π_k (1 − α_k)``.
    """
    K, H, W = alpha.shape
    a = (np.arange(W) + 0.5) / W * 2.0 - 1.0  # in units of R
    out = np.zeros(K)
    for j in range(K):
        phi = math.pi * j / K
        e = np.array([math.cos(phi), math.sin(phi)])
        n = np.array([-math.sin(phi), math.cos(phi)])
        d = -n
        through = np.ones((H, W))
        for k in range(K):
            ang = math.pi * k / K
            u = np.array([math.cos(ang), math.sin(ang)])
            nk = np.array([-math.sin(ang), math.cos(ang)])
            dn = float(d @ nk)
            if abs(dn) < 1e-6:
                continue  # edge-on: invisible
            t = -a * float(e @ nk) / dn
            sk = a * float(e @ u) + t * float(d @ u)
            col = np.floor((sk + 1.0) / 2.0 * W).astype(np.int64)
            ok = (col >= 0) & (col < W)
            ak = np.zeros((H, W))
            ak[:, ok] = alpha[k][:, col[ok]]
            through *= 1.0 - ak
        out[j] = float((1.0 - through).mean())
    return out


def calibrate_opacity(cov: np.ndarray) -> float:
    """Exponent ``γ`` for card opacity ``α = 1 − (1 − a)^γ`` matching the high level's coverage.

    ``cov (K, H, W)`` is the high level's coverage ``a`` seen along each card's
    normal.  Crossed cards stack, so raw ``a`` over-covers; ``γ`` is bisected
    in ``[0.05, 2]`` until the cards' mean coverage over the ``K`` views
    (:func:`card_coverage`) equals the high level's mean coverage.
    """
    target = float(cov.mean())
    if target <= 0:
        return 1.0
    lo, hi = 0.05, 2.0
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        if card_coverage(1.0 - (1.0 - cov) ** mid).mean() > target:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def impostor(
    parts: list[tuple[MeshData, np.ndarray, np.ndarray | None]],
    bounds: np.ndarray,
    *,
    res: int = 128,
    seed: int = 0,
    coverage: np.ndarray | None = None,
    shading: np.ndarray | None = None,
    cut: bool = True,
) -> tuple[MeshData, np.ndarray, np.ndarray]:
    """Crossed-card far form of ``parts`` (mesh, linear colour, RGBA texture or None).

    ``FAR_VIEWS`` vertical cards through the trunk's axis, each textured with the crown seen along its normal,
    and one horizontal card textured with the crown seen from straight above, at the median height of the
    crown's top surface.  Vertical crossed cards alone (the classic crossed-billboard impostor) are edge-on from
    above: seen from 60° up they covered 0.57 of a broadleaf crown's high level and from 85° up 0.32, the
    ground showing between them.  From straight
    above the vertical cards vanish and the horizontal card alone covers what the high level does, so its
    opacity is the top view's coverage as rendered, uncorrected.

    With ``cut`` each card is cut to the outline of its view's alpha
    (:func:`pick_outline` among :func:`forest.library.outline.card_outlines` of
    at most ``MAX_CARD_TRIANGLES["far"]`` triangles): a crown's silhouette fills
    a third of its card or less, and far trees are many.

    ``shading (FAR_TILES, res, res, 3)``, when given, is each view rendered under a
    unit sky (:func:`forest.library.preview.card_view_shading`): albedo times the
    sky's visibility, so the atlas carries the crown's self-occlusion — darker
    inside and below, as the high level renders — which three flat cards lit in a
    scene would otherwise lack.  It replaces the splat's albedo where it hit.

    ``coverage (FAR_TILES, res, res)``, when given, is the exact coverage of
    each view, the view from above last (rendered, :func:`forest.library.preview.card_views`); the
    splat's own estimate over-covers thin geometry by up to half a sub-pixel
    per edge, so it serves only when no rendering is at hand.  Colour always
    comes from the splat (albedo of the nearest surface).

    Returns the card mesh, the RGBA atlas (``res`` high, ``FAR_TILES·res`` wide;
    RGB = albedo / colour scale, clipped at 1) and the colour scale (per-channel
    99th percentile of the albedo), so that ``colour × texture.rgb`` reproduces the albedo
    (the brightest 1 % of texels clip).
    """
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, TAG_LOD, 77])))
    lo, hi = bounds
    radius = float(max(np.abs(lo[[0, 2]]).max(), np.abs(hi[[0, 2]]).max(), 1e-3))
    height = float(max(hi[1] - lo[1], 1e-3))
    # With a rendered coverage the splat only supplies colour: one sub-pixel per
    # pixel and fewer samples do; without, 4×4 sub-pixels estimate the coverage.
    ss = 1 if coverage is not None else 4
    max_samples = MAX_SAMPLES // 4 if coverage is not None else MAX_SAMPLES
    sub = ss * res
    px = 2 * radius / sub
    py = height / sub
    # Two samples per sub-pixel of surface, but at most max_samples in all: dense
    # crowns (many layers deep) saturate the coverage long before that.
    total_area = 0.0
    for mesh, _, _ in parts:
        if len(mesh.faces):
            v = mesh.vertices.astype(np.float64)
            f = mesh.faces.astype(np.int64)
            total_area += 0.5 * float(
                np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
            )
    density = min(2.0 / (px * py), max_samples / max(total_area, 1e-12))
    samples_p, samples_c = [], []
    for mesh, colour, tex in parts:
        if len(mesh.faces) == 0:
            continue
        pos, uv = _sample_surface(mesh, density, rng)
        col = np.broadcast_to(np.asarray(colour, dtype=np.float64), (len(pos), 3)).copy()
        if tex is not None:
            h, w = tex.shape[:2]
            ix = np.clip((uv[:, 0] % 1.0) * w, 0, w - 1).astype(np.int64)
            iy = np.clip((uv[:, 1] % 1.0) * h, 0, h - 1).astype(np.int64)
            texel = tex[iy, ix]
            keep = texel[:, 3] >= 0.5
            pos, col = pos[keep], col[keep] * texel[keep, :3]
        samples_p.append(pos)
        samples_c.append(col)
    P = np.concatenate(samples_p) if samples_p else np.zeros((0, 3))
    C = np.concatenate(samples_c) if samples_c else np.zeros((0, 3))
    for name, given in (("coverage", coverage), ("shading", shading)):
        if given is not None and len(given) != FAR_TILES:
            raise ValueError(
                f"impostor: {name} needs {FAR_TILES} views (the side views, then the top), got {len(given)}"
            )
    atlas = np.zeros((res, FAR_TILES * res, 4), dtype=np.float64)
    verts, uvs, nrms, covs = [], [], [], []
    top_y = 0.5 * (lo[1] + hi[1])
    for k in range(FAR_TILES):
        if k < FAR_VIEWS:
            ang = math.pi * k / FAR_VIEWS
            axis = np.array([math.cos(ang), 0.0, math.sin(ang)])
            normal = np.array([-math.sin(ang), 0.0, math.cos(ang)])
            a = P @ axis
            depth = P @ normal
            iy = np.clip(((hi[1] - P[:, 1]) / height * sub).astype(np.int64), 0, sub - 1)  # row 0 = top
        else:  # from above: columns along x, rows along z (row 0 at z = -R), the highest sample nearest
            a = P[:, 0]
            depth = P[:, 1]
            iy = np.clip(((P[:, 2] + radius) / (2 * radius) * sub).astype(np.int64), 0, sub - 1)
        ix = np.clip(((a + radius) / (2 * radius) * sub).astype(np.int64), 0, sub - 1)
        cell = iy * sub + ix
        # One sort on cell + (normalised distance from the viewer): per cell, the nearest sample first.
        dn = (depth.max() - depth) / max(float(np.ptp(depth)), 1e-9) * 0.999 if len(depth) else depth
        order = np.argsort(cell + dn, kind="stable")
        cs = cell[order]
        first = np.ones(len(cs), dtype=bool)
        first[1:] = cs[1:] != cs[:-1]
        grid = np.zeros((sub * sub, 4))
        grid[cs[first], :3] = C[order][first]
        grid[cs[first], 3] = 1.0
        if k == FAR_VIEWS and first.any():  # the horizontal card lies at the top surface's median height
            top_y = float(np.median(P[order][first][:, 1]))
        grid = grid.reshape(res, ss, res, ss, 4)
        cov = grid[..., 3].mean(axis=(1, 3))
        hits = grid[..., 3].sum(axis=(1, 3))
        rgb = grid[..., :3].sum(axis=(1, 3)) / np.maximum(hits, 1)[..., None]
        if coverage is not None:
            # Pixels the rendering covers but no sample reached take the mean colour.
            mean_rgb = C.mean(axis=0) if len(C) else np.full(3, 0.5)
            rgb = np.where(hits[..., None] > 0, rgb, mean_rgb)
            cov = np.asarray(coverage[k], dtype=np.float64)
        if shading is not None:
            sh = np.asarray(shading[k], dtype=np.float64)
            rgb = np.where(sh.sum(axis=-1, keepdims=True) > 0, sh, rgb)
        atlas[:, k * res : (k + 1) * res, :3] = rgb
        covs.append(cov)
        u0, u1 = k / FAR_TILES, (k + 1) / FAR_TILES
        if k < FAR_VIEWS:
            corners = [-radius * axis + [0, lo[1], 0], radius * axis + [0, lo[1], 0],
                       radius * axis + [0, hi[1], 0], -radius * axis + [0, hi[1], 0]]  # fmt: skip
            uvs.append(np.array([[u0, 1.0], [u1, 1.0], [u1, 0.0], [u0, 0.0]]))
        else:  # corners in the order that winds the faces (0, 1, 2), (0, 2, 3) about +Y
            corners = [[-radius, 0.0, -radius], [-radius, 0.0, radius], [radius, 0.0, radius], [radius, 0.0, -radius]]
            uvs.append(np.array([[u0, 0.0], [u0, 1.0], [u1, 1.0], [u1, 0.0]]))
            normal = np.array([0.0, 1.0, 0.0])
        verts.append(np.array(corners, np.float64))
        nrms.append(np.repeat(normal[None], 4, axis=0))
    verts[FAR_VIEWS][:, 1] = top_y
    cov = np.stack(covs)
    # The vertical cards stack where they cross: their opacity is calibrated to the side views' coverage.  From
    # above they are edge-on, so the horizontal card carries the top view's coverage as it is.
    gamma = calibrate_opacity(cov[:FAR_VIEWS])
    for k in range(FAR_VIEWS):
        atlas[:, k * res : (k + 1) * res, 3] = 1.0 - (1.0 - cov[k]) ** gamma
    atlas[:, FAR_VIEWS * res :, 3] = cov[FAR_VIEWS]
    covered = atlas[..., 3] > 0
    # The 99th percentile, not the maximum: a few bright bark texels would otherwise squeeze
    # the foliage into the bottom of the 8-bit range.
    scale = np.percentile(atlas[..., :3][covered], 99.0, axis=0) if covered.any() else np.ones(3)
    scale = np.maximum(scale, 1e-4)
    atlas[..., :3] = np.where(covered[..., None], np.minimum(atlas[..., :3] / scale, 1.0), 1.0)
    if not cut:
        faces = (np.array([[0, 1, 2], [0, 2, 3]])[None] + 4 * np.arange(FAR_TILES)[:, None, None]).reshape(-1, 3)
        mesh = MeshData(
            np.concatenate(verts).astype(np.float32),
            faces.astype(np.uint32),
            np.concatenate(nrms).astype(np.float32),
            np.concatenate(uvs).astype(np.float32),
        )
    else:
        mesh = _cut_far_cards(atlas[..., 3], radius, lo[1], hi[1], res, top_y)
    return mesh, atlas.astype(np.float32), scale


def split_top(mesh: MeshData) -> tuple[MeshData, MeshData]:
    """The far level's mesh (:func:`impostor`) as its vertical cards and its horizontal card (faces whose normal is
    +Y), each with only its own vertices: two parts, so a recipe's ``[lod_tone]`` can tone them apart."""
    top = mesh.normals[mesh.faces[:, 0].astype(np.int64), 1] > 0.5

    def sub(keep: np.ndarray) -> MeshData:
        f = mesh.faces[keep].astype(np.int64)
        used = np.unique(f)
        remap = np.full(len(mesh.vertices), -1, np.int64)
        remap[used] = np.arange(len(used))
        return MeshData(mesh.vertices[used], remap[f].astype(np.uint32), mesh.normals[used], mesh.uv[used])

    return sub(~top), sub(top)


def _cut_far_cards(alpha: np.ndarray, radius: float, y0: float, y1: float, res: int, top_y: float) -> MeshData:
    """The far cards, card ``k`` cut to the outline of its tile of the atlas ``alpha`` (res, T·res), ``T`` =
    ``FAR_TILES``.

    Vertical card ``k < K`` (``K`` = ``FAR_VIEWS``) spans ``s ∈ [−R, R]`` along
    ``â_k = (cos φ_k, 0, sin φ_k)``, ``φ_k = πk/K``, and ``y ∈ [y0, y1]``; its
    tile's uv ``(u, v)`` maps to ``s = −R + 2R·(u·T − k)`` and
    ``y = y1 − v·(y1 − y0)`` (row 0 at the top).  uv's ``v`` runs down, so the
    outline's counter-clockwise fan is reversed to wind about the card's normal
    ``(−sin φ_k, 0, cos φ_k) = â_k × Ŷ``.  The horizontal card (tile ``K``) lies
    at ``y = top_y``, ``x = −R + 2R·(u·T − K)``, ``z = −R + 2R·v``, wound about ``+Ŷ``.
    """
    from .outline import card_outlines

    verts, uvs, nrms, faces = [], [], [], []
    count = 0
    for k in range(FAR_TILES):
        options = card_outlines(alpha, MAX_CARD_TRIANGLES["far"], rect_px=(k * res, 0, (k + 1) * res, res))
        o = pick_outline(options)
        if o.area >= 1.0:  # nothing to cut: the whole tile
            o = quad((k / FAR_TILES, 0.0, (k + 1) / FAR_TILES, 1.0))
        u, v = o.uv[:, 0], o.uv[:, 1]
        s = -radius + 2.0 * radius * (u * FAR_TILES - k)
        if k < FAR_VIEWS:
            ang = math.pi * k / FAR_VIEWS
            axis = np.array([math.cos(ang), 0.0, math.sin(ang)])
            normal = np.array([-math.sin(ang), 0.0, math.cos(ang)])
            y = y1 - v * (y1 - y0)
            verts.append(s[:, None] * axis + y[:, None] * np.array([0.0, 1.0, 0.0]))
        else:
            normal = np.array([0.0, 1.0, 0.0])
            verts.append(np.stack([s, np.full_like(s, top_y), -radius + 2.0 * radius * v], axis=1))
        fan = o.fan()[:, [0, 2, 1]]
        p = verts[-1]
        if len(fan) and float(np.cross(p[fan[0, 1]] - p[fan[0, 0]], p[fan[0, 2]] - p[fan[0, 0]]) @ normal) < 0:
            fan = fan[:, [0, 2, 1]]
        uvs.append(o.uv)
        nrms.append(np.repeat(normal[None], len(u), axis=0))
        faces.append(fan + count)
        count += len(u)
    return MeshData(
        np.concatenate(verts).astype(np.float32),
        np.concatenate(faces).astype(np.uint32),
        np.concatenate(nrms).astype(np.float32),
        np.concatenate(uvs).astype(np.float32),
    )
