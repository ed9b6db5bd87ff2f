"""The building types: tower, apartment slab, house and warehouse, drawn from a recipe and a stream.

Each builder takes the validated ``[building]`` table and the seed's random
stream and returns ``({lod: {part: PartMesh}}, far box height, its wall height
or None, (W, D))``: the high, medium and low levels' parts (``walls``, ``roof``,
``trim``) and what :func:`forest.library.buildings.kit.far_box` needs for the
far level (see :mod:`forest.library.buildings` for what each level holds).
"""

from __future__ import annotations

import math

import numpy as np

from .facades import ROOF_TILE
from .kit import PartMesh, add_boxes, add_facade_boxes, parapets
from .recipe import LODS


def _draw(rng, r) -> float:
    return float(r[0] + (r[1] - r[0]) * rng.uniform())


def _draw_int(rng, r) -> int:
    return int(rng.integers(int(r[0]), int(r[1]) + 1))


def _parts(b: dict) -> dict:
    tile = ROOF_TILE[b["type"]]
    return {lod: {"walls": PartMesh(), "roof": PartMesh(planar=tile), "trim": PartMesh()} for lod in LODS[:3]}


def _rooftop_units(rng, x0, z0, x1, z1, y, count: int, size=(1.5, 4.0)) -> tuple[np.ndarray, np.ndarray]:
    """``count`` plant boxes (air handlers) inside the roof rectangle, sizes in ``size`` metres."""
    w = rng.uniform(size[0], size[1], (count, 2))
    w = np.minimum(w, [(x1 - x0) * 0.3, (z1 - z0) * 0.3])
    h = rng.uniform(1.0, 2.2, count)
    cx = rng.uniform(x0 + w[:, 0] / 2 + 0.5, x1 - w[:, 0] / 2 - 0.5)
    cz = rng.uniform(z0 + w[:, 1] / 2 + 0.5, z1 - w[:, 1] / 2 - 0.5)
    lo = np.stack([cx - w[:, 0] / 2, np.full(count, y), cz - w[:, 1] / 2], 1)
    hi = np.stack([cx + w[:, 0] / 2, y + h, cz + w[:, 1] / 2], 1)
    return lo, hi


def _tower(b: dict, rng) -> tuple[dict, float, float | None, tuple[float, float]]:
    W, D = _draw(rng, b["width"]), _draw(rng, b["depth"])
    floors = _draw_int(rng, b["floors"])
    fh, bay = b["floor_height"], b["bay"]
    nset = min(_draw_int(rng, b["setbacks"]), max(floors // 4, 0))
    # Tier k holds a share of the floors decreasing upwards, inset by ``setback`` more each side.
    shares = 0.55 ** np.arange(nset + 1)
    fl = np.maximum(1, np.floor(floors * shares / shares.sum())).astype(int)
    fl[0] += floors - fl.sum()
    insets = np.concatenate([[0.0], np.cumsum([_draw(rng, b["setback"]) for _ in range(nset)])])
    insets = np.minimum(insets, 0.35 * min(W, D))
    P = _parts(b)
    y = 0.0
    area_x = area_z = 0.0
    tiers = []
    for k in range(nset + 1):
        x0, x1 = -W / 2 + insets[k], W / 2 - insets[k]
        z0, z1 = -D / 2 + insets[k], D / 2 - insets[k]
        h = fl[k] * fh
        tiers.append((x0, z0, x1, z1, y, y + h))
        area_z += (x1 - x0) * h
        area_x += (z1 - z0) * h
        y += h
    top = tiers[-1]
    tx0, tz0, tx1, tz1, _, ytop = top
    # Penthouse (lift machinery) on the top tier, 40 % of its footprint.
    pw, pd = 0.4 * (tx1 - tx0), 0.4 * (tz1 - tz0)
    ph = 1.2 * fh
    pent = (np.array([-pw / 2, ytop, -pd / 2]), np.array([pw / 2, ytop + ph, pd / 2]))
    area_z += pw * ph
    area_x += pd * ph
    units = _rooftop_units(rng, tx0, tz0, tx1, tz1, ytop, 6)
    spire = rng.uniform() < b["spire_chance"]
    sh = 0.35 * y if spire else 0.0
    for lod in LODS[:3]:
        p = P[lod]
        for x0, z0, x1, z1, y0, y1 in tiers:
            add_facade_boxes(p["walls"], p["roof"], [x0, y0, z0], [x1, y1, z1], bay, fh)
        add_boxes(p["trim"], *pent)
        if lod == "low":
            continue
        for x0, z0, x1, z1, _y0, y1 in tiers:
            parapets(p["walls"], x0, z0, x1, z1, y1, b["parapet"])
        add_boxes(p["trim"], *units)
        if spire:
            add_boxes(p["trim"], [-0.4, ytop + ph, -0.4], [0.4, ytop + ph + sh, 0.4])
        if lod == "high":
            # Vertical fins on every bay line of every tier: thin boxes standing proud of the façade.
            fd, fw = b["fin_depth"], 0.3
            for x0, z0, x1, z1, y0, y1 in tiers:
                nx = max(1, round((x1 - x0) / bay))
                nz = max(1, round((z1 - z0) / bay))
                xs = x0 + (x1 - x0) * np.arange(1, nx) / nx
                zs = z0 + (z1 - z0) * np.arange(1, nz) / nz
                lo = np.concatenate(
                    [
                        np.stack([xs - fw / 2, np.full_like(xs, y0), np.full_like(xs, z1)], 1),
                        np.stack([xs - fw / 2, np.full_like(xs, y0), np.full_like(xs, z0 - fd)], 1),
                        np.stack([np.full_like(zs, x1), np.full_like(zs, y0), zs - fw / 2], 1),
                        np.stack([np.full_like(zs, x0 - fd), np.full_like(zs, y0), zs - fw / 2], 1),
                    ]
                )
                hi = np.concatenate(
                    [
                        np.stack([xs + fw / 2, np.full_like(xs, y1), np.full_like(xs, z1 + fd)], 1),
                        np.stack([xs + fw / 2, np.full_like(xs, y1), np.full_like(xs, z0)], 1),
                        np.stack([np.full_like(zs, x1 + fd), np.full_like(zs, y1), zs + fw / 2], 1),
                        np.stack([np.full_like(zs, x0), np.full_like(zs, y1), zs + fw / 2], 1),
                    ]
                )
                add_boxes(p["trim"], lo, hi)
    return P, (area_x + area_z) / (W + D), None, (W, D)


def _apartment(b: dict, rng) -> tuple[dict, float, float | None, tuple[float, float]]:
    W, D = _draw(rng, b["width"]), _draw(rng, b["depth"])
    floors = _draw_int(rng, b["floors"])
    fh, bay = b["floor_height"], b["bay"]
    H = floors * fh
    x0, x1, z0, z1 = -W / 2, W / 2, -D / 2, D / 2
    bd = b["balcony_depth"]
    nb = max(1, round(W / bay))
    every = b["balcony_every"]
    cols = np.arange(nb)[(np.arange(nb) % every) == (every // 2)]
    # Stair and lift cores on the roof, one per 25 m of slab.
    ncore = max(1, round(W / 25))
    cx = x0 + W * (np.arange(ncore) + 0.5) / ncore
    core = (
        np.stack([cx - 2.0, np.full(ncore, H), np.full(ncore, -2.5)], 1),
        np.stack([cx + 2.0, np.full(ncore, H + 2.8), np.full(ncore, 2.5)], 1),
    )
    P = _parts(b)
    for lod in LODS[:3]:
        p = P[lod]
        add_facade_boxes(p["walls"], p["roof"], [x0, 0.0, z0], [x1, H, z1], bay, fh)
        add_boxes(p["trim"], *core)
        if lod == "low":
            continue
        parapets(p["walls"], x0, z0, x1, z1, H, b["parapet"])
        fl = np.arange(1, floors)
        if bd <= 0 or len(fl) == 0:
            continue
        if lod == "high":
            # One box a balcony (slab + solid balustrade 1.1 m), on every ``every``-th bay, both long faces.
            ua = x0 + W * cols / nb + 0.25
            ub = x0 + W * (cols + 1) / nb - 0.25
            F, C = np.meshgrid(fl, np.arange(len(cols)), indexing="ij")
            yb = (F * fh - 0.2).reshape(-1)
            a, bb = ua[C.reshape(-1)], ub[C.reshape(-1)]
            for s in (1.0, -1.0):
                zin, zout = s * D / 2, s * (D / 2 + bd)
                lo = np.stack([a, yb, np.full_like(a, min(zin, zout))], 1)
                hi = np.stack([bb, yb + 1.3, np.full_like(a, max(zin, zout))], 1)
                add_boxes(p["trim"], lo, hi, bottom=True)
        else:
            # Medium: the balconies of a floor and face merge into one strip over the balconied span.
            if len(cols):
                sa, sb = x0 + W * cols.min() / nb + 0.25, x0 + W * (cols.max() + 1) / nb - 0.25
                yb = fl * fh - 0.2
                for s in (1.0, -1.0):
                    zin, zout = s * D / 2, s * (D / 2 + bd)
                    lo = np.stack([np.full_like(yb, sa), yb, np.full_like(yb, min(zin, zout))], 1)
                    hi = np.stack([np.full_like(yb, sb), yb + 1.3, np.full_like(yb, max(zin, zout))], 1)
                    add_boxes(p["trim"], lo, hi, bottom=True)
    area_z = W * H + ncore * 4.0 * 2.8
    area_x = D * H + ncore * 5.0 * 2.8
    return P, (area_x + area_z) / (W + D), None, (W, D)


def _gable_roof(p: PartMesh, walls: PartMesh, W, D, eave, ridge, oh, thick: float) -> None:
    """A gable roof with the ridge along X: two slopes (slabs of ``thick`` when > 0) and two gable triangles."""
    slope = (ridge - eave) / (D / 2)
    xa, xb = -W / 2 - oh, W / 2 + oh
    ze = D / 2 + oh
    ye = eave - oh * slope
    for s in (1.0, -1.0):
        # Top surface, counter-clockwise seen from above-outside.
        if s > 0:
            top = np.array([[[xa, ye, ze], [xb, ye, ze], [xb, ridge, 0.0], [xa, ridge, 0.0]]])
        else:
            top = np.array([[[xb, ye, -ze], [xa, ye, -ze], [xa, ridge, 0.0], [xb, ridge, 0.0]]])
        p.polys(top)
        if thick > 0:
            bot = top - [0.0, thick, 0.0]
            p.polys(bot[:, ::-1])  # soffit
            e0, e1 = bot[0], top[0]
            # Fascia along the eave and the two verges (edges between top and bottom outlines).
            for i, j in ((0, 1), (3, 0), (1, 2)):
                p.polys(np.array([[e0[i], e0[j], e1[j], e1[i]]]))
    g = np.array(
        [
            [[-W / 2, eave, -D / 2], [-W / 2, eave, D / 2], [-W / 2, ridge, 0.0]],
            [[W / 2, eave, D / 2], [W / 2, eave, -D / 2], [W / 2, ridge, 0.0]],
        ]
    )
    walls.polys(g)


def _house(b: dict, rng) -> tuple[dict, float, float | None, tuple[float, float]]:
    W, D = _draw(rng, b["width"]), _draw(rng, b["depth"])
    if D > W:
        W, D = D, W  # ridge along the long side (X)
    floors = _draw_int(rng, b["floors"])
    fh, bay = b["floor_height"], b["bay"]
    eave = floors * fh
    pitch = math.radians(_draw(rng, b["pitch"]))
    ridge = eave + math.tan(pitch) * D / 2
    oh = b["overhang"]
    chim_x = float(rng.uniform(-0.3, 0.3)) * W
    chim_z = float(rng.choice([-1.0, 1.0])) * D * 0.2
    chim_top = ridge + 0.8
    P = _parts(b)
    for lod in LODS[:3]:
        p = P[lod]
        add_facade_boxes(p["walls"], None, [-W / 2, 0.0, -D / 2], [W / 2, eave, D / 2], bay, fh)
        _gable_roof(p["roof"], p["walls"], W, D, eave, ridge, oh, 0.18 if lod != "low" else 0.0)
        add_boxes(p["trim"], [chim_x - 0.35, eave, chim_z - 0.35], [chim_x + 0.35, chim_top, chim_z + 0.35])
        if lod == "low":
            continue
        if lod == "high":
            # Window sills under every window of the façade tile (u ∈ [0.28, 0.72] of a bay,
            # 16–20 % of a floor above its base), standing 8 cm proud of all four walls.
            nx, nz = max(1, round(W / bay)), max(1, round(D / bay))
            yf = np.arange(floors) * fh
            sx = [(-W / 2 + W * (i + 0.28) / nx, -W / 2 + W * (i + 0.72) / nx) for i in range(nx)]
            sz = [(-D / 2 + D * (i + 0.28) / nz, -D / 2 + D * (i + 0.72) / nz) for i in range(nz)]
            lo, hi = [], []
            for y in yf:
                ya, yb = y + 0.16 * fh, y + 0.2 * fh
                for a, c in sx:
                    lo += [[a, ya, D / 2], [a, ya, -D / 2 - 0.08]]
                    hi += [[c, yb, D / 2 + 0.08], [c, yb, -D / 2]]
                for a, c in sz:
                    lo += [[W / 2, ya, a], [-W / 2 - 0.08, ya, a]]
                    hi += [[W / 2 + 0.08, yb, c], [-W / 2, yb, c]]
            add_boxes(p["walls"], np.array(lo), np.array(hi), bottom=True)
            # Porch on the +Z side at the bay line nearest the middle (between two windows):
            # door, canopy slab on two posts, and a step.
            dx = -W / 2 + W * round(nx / 2) / nx
            dz = D / 2
            add_boxes(p["trim"], [dx - 0.5, 0.0, dz], [dx + 0.5, 2.1, dz + 0.06])  # door
            add_boxes(p["trim"], [dx - 1.3, 2.4, dz], [dx + 1.3, 2.55, dz + 1.5], bottom=True)  # canopy
            add_boxes(
                p["walls"],
                [[dx - 1.25, 0.0, dz + 1.3], [dx + 1.05, 0.0, dz + 1.3]],
                [[dx - 1.05, 2.4, dz + 1.5], [dx + 1.25, 2.4, dz + 1.5]],
            )  # posts
            add_boxes(p["walls"], [dx - 1.3, 0.0, dz], [dx + 1.3, 0.18, dz + 1.6])  # step
    # Silhouettes: along Z (eave side) the roof up to the ridge over W + 2·oh; along X the gable.
    area_z = W * eave + (W + 2 * oh) * (ridge - eave)
    area_x = D * eave + 0.5 * D * (ridge - eave)
    return P, (area_x + area_z) / (W + D), eave, (W, D)


def _warehouse(b: dict, rng) -> tuple[dict, float, float | None, tuple[float, float]]:
    W, D = _draw(rng, b["width"]), _draw(rng, b["depth"])
    H = _draw_int(rng, b["floors"]) * b["floor_height"]
    bay = b["bay"]
    x0, x1, z0, z1 = -W / 2, W / 2, -D / 2, D / 2
    saw = b["roof"] == "sawtooth"
    nt = max(1, round(W / _draw(rng, b["tooth"])))
    rise = _draw(rng, b["tooth_rise"]) if saw else 0.0
    ndoor = _draw_int(rng, b["doors"])
    sky = _rooftop_units(rng, x0, z0, x1, z1, H, 4 * max(1, nt // 2), size=(2.0, 3.0)) if not saw else None
    P = _parts(b)
    for lod in LODS[:3]:
        p = P[lod]
        add_facade_boxes(p["walls"], None if saw else p["roof"], [x0, 0.0, z0], [x1, H, z1], bay, H)
        if saw:
            # Teeth along X: a slope rising over the tooth, then a vertical north light back down.
            e = x0 + W * np.arange(nt + 1) / nt
            a, c = e[:-1], e[1:]
            N = nt
            y0, y1 = np.full(N, H), np.full(N, H + rise)
            slope = np.stack(
                [
                    np.stack([a, y0, np.full(N, z1)], 1),
                    np.stack([c, y1, np.full(N, z1)], 1),
                    np.stack([c, y1, np.full(N, z0)], 1),
                    np.stack([a, y0, np.full(N, z0)], 1),
                ],
                1,
            )
            p["roof"].polys(slope)
            light = np.stack(
                [
                    np.stack([c, y0, np.full(N, z1)], 1),
                    np.stack([c, y0, np.full(N, z0)], 1),
                    np.stack([c, y1, np.full(N, z0)], 1),
                    np.stack([c, y1, np.full(N, z1)], 1),
                ],
                1,
            )
            p["trim"].polys(light)
            ends = np.concatenate(
                [
                    np.stack(
                        [
                            np.stack([a, y0, np.full(N, z1)], 1),
                            np.stack([c, y0, np.full(N, z1)], 1),
                            np.stack([c, y1, np.full(N, z1)], 1),
                        ],
                        1,
                    ),
                    np.stack(
                        [
                            np.stack([c, y0, np.full(N, z0)], 1),
                            np.stack([a, y0, np.full(N, z0)], 1),
                            np.stack([c, y1, np.full(N, z0)], 1),
                        ],
                        1,
                    ),
                ]
            )
            p["walls"].polys(ends)
        # Loading doors on the +Z face with a canopy over them (the canopy down to the low level).
        dx = x0 + W * (np.arange(ndoor) + 0.5) / ndoor
        dw = min(4.0, 0.6 * W / ndoor)
        dh = min(4.5, 0.7 * H)
        add_boxes(p["roof"], [dx[0] - dw, dh + 0.3, z1], [dx[-1] + dw, dh + 0.5, z1 + 2.5], bottom=True)
        if lod == "low":
            continue
        if sky is not None:
            add_boxes(p["trim"], sky[0], sky[1][:, :] * [1, 0, 1] + [0, H + 0.6, 0])
        parapets(p["walls"], x0, z0, x1, z1, H, 0.0 if saw else b["parapet"])
        add_boxes(
            p["trim"],
            np.stack([dx - dw / 2, np.zeros(ndoor), np.full(ndoor, z1)], 1),
            np.stack([dx + dw / 2, np.full(ndoor, dh), np.full(ndoor, z1 + 0.08)], 1),
        )
        if lod == "high":
            # Pilasters every two bays around the perimeter.
            nx, nz = max(1, round(W / (2 * bay))), max(1, round(D / (2 * bay)))
            xs = x0 + W * np.arange(nx + 1) / nx
            zs = z0 + D * np.arange(1, nz) / nz
            t, d = 0.5, 0.3
            lo = np.concatenate(
                [
                    np.stack([xs - t / 2, np.zeros_like(xs), np.full_like(xs, z1)], 1),
                    np.stack([xs - t / 2, np.zeros_like(xs), np.full_like(xs, z0 - d)], 1),
                    np.stack([np.full_like(zs, x1), np.zeros_like(zs), zs - t / 2], 1),
                    np.stack([np.full_like(zs, x0 - d), np.zeros_like(zs), zs - t / 2], 1),
                ]
            )
            hi = np.concatenate(
                [
                    np.stack([xs + t / 2, np.full_like(xs, H), np.full_like(xs, z1 + d)], 1),
                    np.stack([xs + t / 2, np.full_like(xs, H), np.full_like(xs, z0)], 1),
                    np.stack([np.full_like(zs, x1 + d), np.full_like(zs, H), zs + t / 2], 1),
                    np.stack([np.full_like(zs, x0), np.full_like(zs, H), zs + t / 2], 1),
                ]
            )
            add_boxes(p["walls"], lo, hi)
    area_z = W * (H + rise / 2)
    area_x = D * (H + rise)
    return P, (area_x + area_z) / (W + D), None, (W, D)


BUILDERS = {"tower": _tower, "apartment": _apartment, "house": _house, "warehouse": _warehouse}
