"""Card outlines: the convex polygon of a card's uv rectangle that holds every texel the card can show.

A leaf card is a quad whose texture's alpha cuts the leaf out.  A ray that hits
the quad where alpha is 0 is skipped by the renderer — at the price of a fresh
traversal of the scene — so a card that is mostly transparent costs several
traversals per leaf hit (a needle fan covers 23 % of its quad, a leaf cluster
29–48 %, a far impostor card 12–36 %).  Cutting the card to an outline that
encloses the leaf removes most of those hits; the alpha test stays for the
partial texels left inside, so nothing the card shows changes.

**Support.**  Renderers look textures up with bilinear filtering between texel
centres (Mitsuba's ``bitmap``, forest's path tracer): texel ``j`` of ``n``
contributes to lookups at ``u·n ∈ (j − ½, j + 3⁄2)``.  The *support* of a
texture is the union of those squares over the texels with alpha > 0 (with the
texture's wrap-around at its edges), clipped to the card's rectangle: outside
it every lookup returns alpha 0.

**Outline.**  The convex hull ``H`` of the support (Qhull, via SciPy) is reduced
to fewer vertices by greedy edge removal: removing edge ``(b, c)`` of a convex
polygon ``… a b c d …`` and extending ``ab`` and ``dc`` until they meet at
``x`` gives a convex polygon with one vertex less that still contains ``H``;
each step removes the edge whose triangle ``(b, x, c)`` adds the least area.
This is the classic heuristic for the minimum-area circumscribing ``k``-gon
(the problem of A. Aggarwal, J. S. Chang and C. K. Yap, "Minimum area
circumscribing polygons", *The Visual Computer* 1(2): 112–117, 1985).  Two runs
give the candidates: one that never lets ``x`` leave the card's rectangle and one
that does and clips the result to the rectangle afterwards (Sutherland–Hodgman);
a convex polygon of ``k`` vertices is ``k − 2`` triangles (a fan).  Every
candidate contains the support, so the cut card renders what the quad did.

:func:`card_outline` picks, among the candidates of at most ``max_triangles``
triangles, the one of least area; :attr:`Outline.fill` (mean alpha over the
outline) is the share of the rays hitting the cut card that stop on the leaf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Candidates differing by less than this share of the rectangle's area count as equal (fewer triangles win).
AREA_TOLERANCE = 1e-3
#: Alpha thresholds whose supports give candidates (0: the exact support).
THRESHOLDS = (0.0, 0.05, 0.2, 0.5)
#: Largest share of the texture's alpha (summed over texel centres) an outline may leave outside.
MAX_LOSS = 0.01


@dataclass(frozen=True)
class Outline:
    """A convex polygon in uv, counter-clockwise in (u, v), and what it holds.

    ``uv (K, 2)`` vertices; ``area`` its area as a share of the rectangle it was
    cut from; ``coverage`` the texture's mean alpha over that rectangle.
    """

    uv: np.ndarray
    area: float
    coverage: float

    @property
    def triangles(self) -> int:
        """Triangles of the outline's fan: its K vertices less 2."""
        return len(self.uv) - 2

    @property
    def fill(self) -> float:
        """Mean alpha over the outline: the share of the rays hitting the cut card that stop on it."""
        return self.coverage / max(self.area, 1e-12)

    def fan(self) -> np.ndarray:
        """``(K − 2, 3)`` vertex indices of the fan ``(0, i, i + 1)``, counter-clockwise like the polygon."""
        k = np.arange(1, len(self.uv) - 1)
        return np.stack([np.zeros_like(k), k, k + 1], axis=1)


def quad(rect: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 1.0), coverage: float = 1.0) -> Outline:
    """The whole rectangle ``(u0, v0, u1, v1)`` as an outline (the uncut card)."""
    u0, v0, u1, v1 = rect
    return Outline(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], np.float64), 1.0, coverage)


def polygon_area(p: np.ndarray) -> float:
    """Signed area of a polygon (shoelace formula): positive when counter-clockwise."""
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def support_points(alpha: np.ndarray, rect_px: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Corners of the bilinear support of ``alpha > 0`` in pixel units, clipped to ``rect_px``.

    ``alpha (H, W)``; pixel ``(i, j)`` (row, column) spans ``[j, j+1] × [i, i+1]``
    and its support square is that square grown by half a pixel.  The image
    wraps around (a texture repeats), so a texel on one edge also reaches past
    the opposite edge.  ``rect_px = (x0, y0, x1, y1)`` (default: the whole image).
    Returns ``(P, 2)`` points ``(x, y)``; only texels next to an empty texel
    contribute (interior corners cannot be on the hull).
    """
    h, w = alpha.shape
    x0, y0, x1, y1 = rect_px if rect_px is not None else (0, 0, w, h)
    m = np.pad(np.asarray(alpha) > 0.0, 1, mode="wrap")
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    edge = np.pad(inner, 1) ^ m  # texels with alpha > 0 next to an empty one (and the wrapped border)
    i, j = np.nonzero(edge & m)
    i, j = i - 1, j - 1  # padded → image coordinates (−1 and H/W are the wrapped copies)
    lo_x, hi_x = np.clip(j - 0.5, x0, x1), np.clip(j + 1.5, x0, x1)
    lo_y, hi_y = np.clip(i - 0.5, y0, y1), np.clip(i + 1.5, y0, y1)
    keep = (lo_x < hi_x) & (lo_y < hi_y)
    lo_x, hi_x, lo_y, hi_y = lo_x[keep], hi_x[keep], lo_y[keep], hi_y[keep]
    pts = np.concatenate(
        [np.stack(c, axis=1) for c in ((lo_x, lo_y), (hi_x, lo_y), (hi_x, hi_y), (lo_x, hi_y))], axis=0
    ).astype(np.float64)
    return pts if len(pts) else np.zeros((0, 2))


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull of ``points``, counter-clockwise (Qhull through SciPy)."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(points)
    return points[hull.vertices]  # SciPy orders 2-D hull vertices counter-clockwise


def _line_meet(a: np.ndarray, b: np.ndarray, d: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, bool]:
    """Where ray ``a → b`` extended past ``b`` meets ray ``d → c`` extended past ``c`` (and whether it does)."""
    r, s = b - a, c - d
    den = r[0] * s[1] - r[1] * s[0]
    if abs(den) < 1e-15:
        return b, False
    q = d - a
    t = (q[0] * s[1] - q[1] * s[0]) / den
    w = (q[0] * r[1] - q[1] * r[0]) / den
    return a + t * r, bool(t >= 1.0 - 1e-9 and w >= 1.0 - 1e-9)


def reduce_polygon(hull: np.ndarray, rect: tuple[float, float, float, float] | None) -> list[np.ndarray]:
    """Greedy edge removal from a convex, counter-clockwise ``hull`` down to 3 vertices.

    Returns the polygon after each step (longest first).  With ``rect`` an edge
    whose meeting point would leave the rectangle ``(x0, y0, x1, y1)`` is not removed.
    """
    p = [np.asarray(v, np.float64) for v in hull]
    out = [np.array(p)]
    while len(p) > 3:
        best: tuple[float, int, np.ndarray] | None = None
        n = len(p)
        for i in range(n):
            a, b, c, d = p[i - 1], p[i], p[(i + 1) % n], p[(i + 2) % n]
            x, ok = _line_meet(a, b, d, c)
            if not ok:
                continue
            if rect is not None and not (
                rect[0] - 1e-9 <= x[0] <= rect[2] + 1e-9 and rect[1] - 1e-9 <= x[1] <= rect[3] + 1e-9
            ):
                continue
            added = 0.5 * abs((c[0] - b[0]) * (x[1] - b[1]) - (c[1] - b[1]) * (x[0] - b[0]))
            if best is None or added < best[0]:
                best = (added, i, x)
        if best is None:
            break
        _, i, x = best
        p[i] = x
        del p[(i + 1) % len(p)]
        out.append(np.array(p))
    return out


def clip_polygon(p: np.ndarray, axis: int, value: float, keep_above: bool) -> np.ndarray:
    """Sutherland–Hodgman: the part of convex polygon ``p`` with coordinate ``axis`` ≥ ``value`` (or ≤)."""
    if len(p) == 0:
        return p
    s = (p[:, axis] - value) * (1.0 if keep_above else -1.0)
    out = []
    n = len(p)
    for k in range(n):
        a, b = p[k], p[(k + 1) % n]
        sa, sb = s[k], s[(k + 1) % n]
        if sa >= 0:
            out.append(a)
        if (sa >= 0) != (sb >= 0):
            t = sa / (sa - sb)
            q = a + t * (b - a)
            q[axis] = value
            out.append(q)
    return simplify(np.array(out)) if out else np.zeros((0, 2))


def clip_rect(p: np.ndarray, rect: tuple[float, float, float, float]) -> np.ndarray:
    """Convex polygon ``p`` clipped to the rectangle ``(x0, y0, x1, y1)``."""
    for axis, value, above in ((0, rect[0], True), (0, rect[2], False), (1, rect[1], True), (1, rect[3], False)):
        p = clip_polygon(p, axis, value, above)
    return p


def simplify(p: np.ndarray, eps: float = 1e-9) -> np.ndarray:
    """Drop repeated and collinear vertices of a polygon."""
    changed = True
    while changed and len(p) >= 3:
        changed = False
        n = len(p)
        for k in range(n):
            a, b, c = p[k - 1], p[k], p[(k + 1) % n]
            cross = (b[0] - a[0]) * (c[1] - b[1]) - (b[1] - a[1]) * (c[0] - b[0])
            if np.abs(b - a).max() < eps or abs(cross) < eps * eps:
                p = np.delete(p, k, axis=0)
                changed = True
                break
    return p


def lost_share(alpha: np.ndarray, poly_px: np.ndarray, rect_px: tuple[int, int, int, int]) -> float:
    """Share of the alpha summed over the texel centres of ``rect_px`` that lie outside convex ``poly_px``."""
    x0, y0, x1, y1 = rect_px
    a = np.asarray(alpha, np.float64)[y0:y1, x0:x1]
    total = float(a.sum())
    if total <= 0:
        return 0.0
    ii, jj = np.nonzero(a > 0)
    px, py = jj + x0 + 0.5, ii + y0 + 0.5
    inside = np.ones(len(px), bool)
    n = len(poly_px)
    for k in range(n):
        (ax, ay), (bx, by) = poly_px[k], poly_px[(k + 1) % n]
        inside &= (bx - ax) * (py - ay) - (by - ay) * (px - ax) >= -1e-9
    return float(a[ii[~inside], jj[~inside]].sum()) / total


def is_convex(p: np.ndarray) -> bool:
    """Whether polygon ``p`` is convex and counter-clockwise (all turns left, within rounding)."""
    d = np.roll(p, -1, axis=0) - p
    e = np.roll(d, -1, axis=0)
    return bool(((d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0]) >= -1e-9).all())


def candidates(alpha: np.ndarray, rect_px: tuple[int, int, int, int] | None = None) -> list[tuple[np.ndarray, bool]]:
    """Convex outlines (pixel units) of ``alpha`` within ``rect_px``, each with whether it holds the whole support.

    For every threshold ``τ`` of :data:`THRESHOLDS`, the hull of the support of
    ``alpha > τ`` reduced by :func:`reduce_polygon` three ways: never leaving the
    rectangle; unconstrained, then clipped to the rectangle (more vertices); and
    unconstrained with the vertices that left the rectangle pulled back onto it
    (same vertices, a little of the support left out).  Only the clipped
    polygons of ``τ = 0`` are exact; the others must be checked with
    :func:`lost_share`.  Empty when nothing has alpha > 0.
    """
    h, w = alpha.shape
    x0, y0, x1, y1 = rect_px if rect_px is not None else (0, 0, w, h)
    r_px = (x0, y0, x1, y1)
    rect = (float(x0), float(y0), float(x1), float(y1))
    a = np.asarray(alpha, np.float64)
    out: list[tuple[np.ndarray, bool]] = []
    for tau in THRESHOLDS:
        pts = support_points(a > tau, r_px) if tau > 0 else support_points(a, r_px)
        if len(pts) < 3:
            continue
        hull = convex_hull(pts)
        out += [(q, tau == 0) for q in reduce_polygon(hull, rect)]
        for q in reduce_polygon(hull, None):
            out.append((clip_rect(q, rect), tau == 0))
            pulled = simplify(np.clip(q, [rect[0], rect[1]], [rect[2], rect[3]]))
            if len(pulled) >= 3 and is_convex(pulled):
                out.append((pulled, False))
    return [(q, exact) for q, exact in out if len(q) >= 3]


def card_outlines(
    alpha: np.ndarray,
    max_triangles: int,
    rect_px: tuple[int, int, int, int] | None = None,
    max_loss: float = MAX_LOSS,
) -> dict[int, Outline]:
    """For ``t = 2 … max_triangles``, the least-area convex outline of at most ``t`` triangles around ``alpha``.

    ``alpha (H, W)`` in [0, 1], row 0 at ``v = 0`` (Mitsuba's uv convention);
    ``rect_px`` the card's rectangle in pixels (default the whole image).
    Candidates (:func:`candidates`) that leave more than ``max_loss`` of the
    alpha outside (:func:`lost_share`) are refused.  Outlines are in the image's
    uv (``u = x / W``, ``v = y / H``); where no candidate beats the rectangle,
    the rectangle itself is the outline.
    """
    h, w = alpha.shape
    x0, y0, x1, y1 = rect_px if rect_px is not None else (0, 0, w, h)
    r_px = (x0, y0, x1, y1)
    area = float((x1 - x0) * (y1 - y0))
    coverage = float(np.asarray(alpha, np.float64)[y0:y1, x0:x1].mean())
    cands = candidates(alpha, r_px)
    ranked = sorted(
        ((polygon_area(q) / area, len(q) - 2, k) for k, (q, _) in enumerate(cands)),
        key=lambda c: (round(c[0] / AREA_TOLERANCE), c[1]),
    )
    checked: dict[int, bool] = {}
    out: dict[int, Outline] = {}
    for t in range(2, max_triangles + 1):
        best = out.get(t - 1, quad((x0 / w, y0 / h, x1 / w, y1 / h), coverage))
        for a, tris, k in ranked:
            if tris > t or a >= best.area - AREA_TOLERANCE:
                continue
            q, exact = cands[k]
            if k not in checked:
                checked[k] = exact or lost_share(alpha, q, r_px) <= max_loss
            if checked[k]:
                best = Outline(q * np.array([1.0 / w, 1.0 / h]), a, coverage)
                break
        out[t] = best
    return out


def card_outline(
    alpha: np.ndarray,
    max_triangles: int,
    rect_px: tuple[int, int, int, int] | None = None,
    max_loss: float = MAX_LOSS,
) -> Outline:
    """The least-area convex outline of at most ``max_triangles`` triangles around ``alpha`` (see :func:`card_outlines`)."""
    return card_outlines(alpha, max_triangles, rect_px, max_loss)[max_triangles]
