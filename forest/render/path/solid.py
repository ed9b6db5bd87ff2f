"""Solid cards: cut-out leaf cards replaced by opaque ones of the same coverage, for small trees.

A ray that meets a cut-out texel passes it and is traced again from there: one
more traversal of the whole scene (:meth:`forest.render.path.integrator.PathKernel.trace`).
On a forest seen from afar most of those restarts are on leaf-cluster cards whose
texture is mostly gaps (a conifer's needle cluster covers 29 % of its card), and
they are nearly half of all the segments a path traces.  Where a card covers a
pixel or less the shape of its texels cannot be seen, only how much of the card
they cover, so a card can be drawn as an opaque sheet of the same covered area:
each triangle T with alpha coverage

    c_T = (1 / |T|) ∫_T α(uv(x)) dx

is scaled about its alpha-weighted centroid x̄_T = ∫_T α x dx / ∫_T α dx by √c_T,
so its area becomes c_T·|T| — the projected leaf area of every view, and so the
crown's mean coverage, its shadow's mean transmittance and its colour, are kept —
and its material loses the texture: the colour becomes c_m times the
alpha-weighted mean of the texture's RGB (the cluster textures are a white
modulation, 0.98 there).  Opaque sheets end the restarts: a ray either meets one
and stops or passes between them without a hit.

This is the stochastic-transparency-to-geometry step of level-of-detail foliage
(the low level is already a thinned set of cluster cards whose area preserves the
high level's, see ``forest.library.lod``); what it changes is where within a card
the covered texels lie, below a pixel at the levels it is used for.  The
integrals are estimated with the midpoint rule on 64 equal cells of each triangle
and bilinear texture lookups that repeat like the renderer's, so the result is
deterministic.

**Cache.**  A library part's solid mesh is a function of its mesh and texture files alone, so it is
kept in forest's cache folder (:mod:`forest.cache`, ``solid/``) under a hash of both files' bytes and
of this rule's parameters: a render reads it instead of computing it again (on the demo, 24 parts,
about 2.3 s of a 2-core machine's scene load).  An entry that cannot be read is computed again, and
one that cannot be written is only not kept.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ...library.mesh import read_ply
from .inputs import Material
from .materials import texture_rgba

#: Samples per triangle side of the barycentric pattern (SAMPLES² samples in all).
SAMPLES = 8
#: Triangles covering less than this share of their area are dropped.
MIN_COVERAGE = 1e-3
#: Largest alpha-weighted coefficient of variation of a texture's RGB (any channel) for which its cards are
#: drawn solid.  The library's leaf and cluster textures are a near-white modulation (0.009–0.046); its far
#: impostors hold bark and leaves in colour (0.47–1.46) and keep their cut-outs, since one colour per card
#: would lose the trunk.
MAX_RGB_CV = 0.1
#: The rule's version in the cache key: bump it when :func:`solid_cards` changes what it computes.
CACHE_VERSION = 1


@dataclass(frozen=True)
class SolidMesh:
    """An opaque replacement mesh (one vertex per triangle corner) and its texture's mean RGB."""

    vertices: np.ndarray  # (3F, 3) float32
    faces: np.ndarray  # (F, 3) uint32
    normals: np.ndarray | None  # (3F, 3) float32 or None
    uv: np.ndarray  # (3F, 2) float32: the original corners' uv (no texture reads them)
    rgb: np.ndarray  # (3,) float32: alpha-weighted mean texture RGB
    coverage: float  # area-weighted mean alpha coverage of the input's triangles


def modulation(rgba: np.ndarray) -> bool:
    """Whether a texture with alpha is a plain modulation: its RGB over the covered texels varies by at most
    :data:`MAX_RGB_CV` of its mean (alpha-weighted), and it has a cut-out (alpha below 1 somewhere)."""
    a = np.clip(np.asarray(rgba[..., 3], np.float64), 0.0, 1.0)
    total = a.sum()
    if total <= 0.0 or float(a.min()) >= 1.0:
        return False
    rgb = np.asarray(rgba[..., :3], np.float64)
    mean = (rgb * a[..., None]).sum(axis=(0, 1)) / total
    var = (((rgb - mean) ** 2) * a[..., None]).sum(axis=(0, 1)) / total
    return bool(np.all(np.sqrt(var) <= MAX_RGB_CV * np.maximum(mean, 1e-6)))


def barycentric_pattern(n: int = SAMPLES) -> np.ndarray:
    """(n², 3) barycentric points, one per cell of the triangle split into n² congruent triangles: their centroids.

    The edges cut at multiples of 1/n give n(n + 1)/2 upward cells with centroids
    ((i + ⅓)/n, (j + ⅓)/n), i + j ≤ n − 1, and n(n − 1)/2 downward ones at
    ((i + ⅔)/n, (j + ⅔)/n), i + j ≤ n − 2: equal areas, every point strictly
    inside, and their mean the triangle's centroid (the midpoint rule on each cell).
    """
    gi, gj = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    i, j = gi.ravel(), gj.ravel()
    up, down = i + j <= n - 1, i + j <= n - 2
    u = np.concatenate([(i[up] + 1 / 3) / n, (i[down] + 2 / 3) / n])
    v = np.concatenate([(j[up] + 1 / 3) / n, (j[down] + 2 / 3) / n])
    return np.stack([1.0 - u - v, u, v], axis=1)


def bilinear_repeat(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """``image`` (H, W, C) at ``uv`` (..., 2) with bilinear filtering between texel centres, repeating.

    v = 0 is the image's first row (Mitsuba's convention), as in the renderer's atlas lookups.
    """
    h, w = image.shape[:2]
    x = uv[..., 0] * w - 0.5
    y = uv[..., 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x0i, y0i = x0.astype(np.int64) % w, y0.astype(np.int64) % h
    x1i, y1i = (x0i + 1) % w, (y0i + 1) % h
    top = image[y0i, x0i] * (1 - fx) + image[y0i, x1i] * fx
    bottom = image[y1i, x0i] * (1 - fx) + image[y1i, x1i] * fx
    out: np.ndarray = top * (1 - fy) + bottom * fy
    return out


def solid_cards(
    vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, normals: np.ndarray | None, rgba: np.ndarray
) -> SolidMesh:
    """Each textured triangle shrunk to its alpha coverage about its alpha-weighted centroid (module docstring)."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    t = np.asarray(uv, np.float64).reshape(-1, 2)
    b = barycentric_pattern()  # (S, 3)
    uv_s = np.einsum("sk,fkc->fsc", b, t[f])  # (F, S, 2)
    texel = bilinear_repeat(np.asarray(rgba, np.float32), uv_s)  # (F, S, 4)
    alpha = np.clip(texel[..., 3].astype(np.float64), 0.0, 1.0)
    cover = alpha.mean(axis=1)  # (F,)
    weight = alpha.sum(axis=1)
    bw = np.einsum("fs,sk->fk", alpha, b) / np.maximum(weight, 1e-12)[:, None]  # alpha-weighted barycentre
    corners = v[f]  # (F, 3, 3)
    centre = np.einsum("fk,fkc->fc", bw, corners)
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    keep = cover >= MIN_COVERAGE
    s = np.sqrt(cover[keep])[:, None, None]
    shrunk = centre[keep, None, :] + s * (corners[keep] - centre[keep, None, :])
    n_keep = int(keep.sum())
    new_faces = np.arange(3 * n_keep, dtype=np.uint32).reshape(-1, 3)
    w_rgb = alpha * area[:, None]
    total = w_rgb.sum()
    rgb = (texel[..., :3] * w_rgb[..., None]).sum(axis=(0, 1)) / total if total > 0 else np.ones(3)
    nrm = None
    if normals is not None and np.shape(normals) == v.shape:
        nrm = np.asarray(normals, np.float32)[f[keep]].reshape(-1, 3)
    return SolidMesh(
        vertices=shrunk.reshape(-1, 3).astype(np.float32),
        faces=new_faces,
        normals=nrm,
        uv=t[f[keep]].reshape(-1, 2).astype(np.float32),
        rgb=np.asarray(rgb, np.float32),
        coverage=float((cover * area).sum() / max(area.sum(), 1e-12)),
    )


def modulation_rgba(tex: Any) -> np.ndarray | None:
    """The RGBA of texture ``tex`` (an image path or an (h, w, 4) array) when it is a cut-out modulation
    (:func:`modulation`), else None."""
    if tex is None:
        return None
    if isinstance(tex, np.ndarray):
        rgba = np.asarray(tex, np.float32)
        return rgba if rgba.ndim == 3 and rgba.shape[2] == 4 and modulation(rgba) else None
    return _modulation_file(str(tex))


@lru_cache(maxsize=64)
def _modulation_file(path: str) -> np.ndarray | None:
    rgba = texture_rgba(path)
    return rgba if modulation(rgba) else None


def can_draw_solid(part: Any) -> bool:
    """Whether ``part`` (a library ``Part`` or a :class:`~.inputs.Material`) is a leaf with a cut-out modulation."""
    return getattr(part, "kind", "surface") == "leaf" and modulation_rgba(getattr(part, "texture", None)) is not None


@lru_cache(maxsize=128)
def _solid_file(mesh_path: str, texture_path: str) -> SolidMesh:
    """:func:`solid_cards` of a part's mesh file and texture file, kept for the scenes rebuilt in this process
    (other views of look-dev, a service's jobs) and in the cache folder for the processes after it."""
    entry = cache_entry(mesh_path, texture_path)
    kept = read_entry(entry)
    if kept is not None:
        return kept
    mesh = read_ply(mesh_path)
    rgba = _modulation_file(texture_path)
    assert rgba is not None
    sm = solid_cards(mesh.vertices, mesh.faces, mesh.uv, mesh.normals, rgba)
    write_entry(entry, sm)
    return sm


def cache_entry(mesh_path: str | Path, texture_path: str | Path) -> Path:
    """The cache file of a part's solid mesh: ``solid/<hash>.npz``, the hash of the rule's version and
    parameters and of the mesh's and the texture's bytes (so a rebuilt library part gets a new entry)."""
    from ...cache import cache_folder

    h = hashlib.sha256(f"forest solid cards v{CACHE_VERSION} {SAMPLES} {MIN_COVERAGE!r}".encode())
    for path in (mesh_path, texture_path):
        h.update(hashlib.sha256(Path(path).read_bytes()).digest())
    return cache_folder("solid") / f"{h.hexdigest()[:40]}.npz"


def read_entry(path: Path) -> SolidMesh | None:
    """The solid mesh kept in ``path``, or None when there is none or it cannot be read as one."""
    try:
        with np.load(path, allow_pickle=False) as z:
            f = np.asarray(z["faces"], np.uint32)
            sm = SolidMesh(
                vertices=np.asarray(z["vertices"], np.float32),
                faces=f,
                normals=np.asarray(z["normals"], np.float32) if z["normals"].size else None,
                uv=np.asarray(z["uv"], np.float32),
                rgb=np.asarray(z["rgb"], np.float32),
                coverage=float(z["coverage"]),
            )
    except (OSError, ValueError, KeyError, TypeError, EOFError):
        return None
    n = 3 * len(f)
    ok = (
        f.ndim == 2
        and f.shape[1] == 3
        and sm.vertices.shape == (n, 3)
        and sm.uv.shape == (n, 2)
        and sm.rgb.shape == (3,)
        and (sm.normals is None or sm.normals.shape == (n, 3))
        and (n == 0 or int(f.max()) < n)
        and bool(np.isfinite(sm.vertices).all() and np.isfinite(sm.rgb).all())
    )
    return sm if ok else None


def write_entry(path: Path, sm: SolidMesh) -> None:
    """Keep ``sm`` in ``path`` (written whole or not at all); a folder that cannot be written is left alone."""
    from ...atomic import atomic_path
    from ...errors import ForestError

    buf = io.BytesIO()
    normals = np.zeros((0, 3), np.float32) if sm.normals is None else sm.normals
    np.savez(buf, vertices=sm.vertices, faces=sm.faces, normals=normals, uv=sm.uv, rgb=sm.rgb,
             coverage=np.float64(sm.coverage))  # fmt: skip
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(buf.getvalue())
    except (OSError, ForestError):
        pass


def solid_part(mesh: Any, part: Any) -> tuple[Any, Any]:
    """``mesh`` and ``part`` drawn with solid cards: the :class:`SolidMesh` and a textureless leaf
    :class:`~.inputs.Material` of colour c_m × the texture's mean RGB; both unchanged unless ``part`` is a leaf
    with a cut-out modulation texture and ``mesh`` has uv."""
    tex = getattr(part, "texture", None)
    rgba = modulation_rgba(tex) if getattr(part, "kind", "surface") == "leaf" else None
    if rgba is None or getattr(mesh, "uv", None) is None:
        return mesh, part
    path = getattr(part, "path", None)
    if path is not None and not isinstance(tex, np.ndarray):
        sm = _solid_file(str(path), str(tex))
    else:
        sm = solid_cards(mesh.vertices, mesh.faces, mesh.uv, getattr(mesh, "normals", None), rgba)
    material = Material(
        "leaf",
        tuple(float(c) * float(k) for c, k in zip(part.colour, sm.rgb)),
        None,
        bool(getattr(part, "tinted", False)),
        float(getattr(part, "translucency", 0.0) or 0.0),
        float(getattr(part, "sheen", 0.0) or 0.0),
        float(getattr(part, "roughness", 0.0) or 0.0),
    )
    return sm, material
