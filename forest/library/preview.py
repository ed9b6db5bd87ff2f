"""Preview images of species, rendered with Mitsuba 3 (``scalar_rgb``).

Framing: a perspective camera with a 30° field of view looks at the centre of
the level's bounding box from the front (+Z), 12° above the horizon, at the
distance ``d = 1.1·½·max(height, width, depth) / tan(fov/2) + ½·depth`` so the
whole bounding box fits in the frame.  Light: a neutral constant
environment (radiance 0.55) plus a white sun (irradiance 2.2) from the upper
front left.  The film is RGBA with the background transparent (hidden
emitter), so the alpha channel is the tree's coverage — comparable between
levels of detail of one species, which share the framing of the high level.

Materials: bark diffuse with reflectance ``colour × bark.exr`` (a tileable
detail of mean 1); leaves ``mask`` (opacity = texture alpha) over a two-sided
diffuse whose reflectance is ``colour × texture.rgb``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

PREVIEW_SIZE = (192, 192)
PREVIEW_SPP = 16
FOV = 30.0
MAX_DEPTH = 24


def _texture_arrays(path: Path, cache: dict) -> tuple[np.ndarray, np.ndarray]:
    """(linear RGB detail, straight alpha ``(H, W, 1)``) of a texture, cached per render."""
    if path not in cache:
        from .textures import read_texture

        img = read_texture(path)
        cache[path] = (np.ascontiguousarray(img[..., :3]), np.ascontiguousarray(img[..., 3:4]))
    return cache[path]


def part_bsdf(mi, part, cache: dict | None = None) -> dict:
    """A Mitsuba BSDF dictionary for ``part`` (used by previews; renderers may reuse it)."""
    cache = {} if cache is None else cache
    colour = np.asarray(part.colour, dtype=np.float32)
    if part.texture is None:
        diffuse = {"type": "diffuse", "reflectance": {"type": "rgb", "value": colour.tolist()}}
        return {"type": "twosided", "material": diffuse} if part.kind != "bark" else diffuse
    rgb, alpha = _texture_arrays(part.texture, cache)
    refl = {
        "type": "bitmap",
        "bitmap": mi.Bitmap(np.ascontiguousarray(rgb * colour)),
        "raw": True,
        "filter_type": "bilinear",
    }
    diffuse = {"type": "twosided", "material": {"type": "diffuse", "reflectance": refl}}
    if part.kind == "leaf" or alpha.min() < 1.0:
        return {
            "type": "mask",
            "opacity": {"type": "bitmap", "bitmap": mi.Bitmap(alpha), "raw": True, "filter_type": "bilinear"},
            "material": diffuse,
        }
    return diffuse


def camera_for(bounds: np.ndarray, size: tuple[int, int], elevation: float = 12.0) -> dict:
    """A ``perspective`` sensor dict framing ``bounds`` in a ``size`` (width, height) image, seen from +Z,
    ``elevation`` degrees up (below 90).

    ``_eye`` and ``_target`` stand in for ``to_world`` (built once the variant is set).
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    centre = 0.5 * (lo + hi)
    r = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3)
    aspect = size[0] / size[1]
    half = math.radians(FOV / 2)
    if aspect < 1:  # fov applies to the wider axis; keep the sphere inside the narrow one
        half = math.atan(math.tan(half) * aspect)
    # Fit the box's front face (width × height) in the view, plus half its depth.
    ext = hi - lo
    d = 1.1 * 0.5 * max(ext[1], ext[0] / max(aspect, 1e-3), ext[2]) / math.tan(half) + 0.5 * ext[2]
    d = max(d, 1.05 * r)
    el = math.radians(float(elevation))
    eye = centre + d * np.array([0.0, math.sin(el), math.cos(el)])
    return {
        "type": "perspective",
        "fov": FOV,
        "fov_axis": "larger",
        "near_clip": max(d - 2 * r, 1e-3) * 0.5,
        "far_clip": d + 2 * r,
        "to_world": None,
        "_eye": eye.tolist(),
        "_target": centre.tolist(),
    }


def render_lod(
    species,
    lod: str = "high",
    *,
    size: tuple[int, int] = PREVIEW_SIZE,
    spp: int = PREVIEW_SPP,
    frame_bounds: np.ndarray | None = None,
    elevation: float = 12.0,
) -> np.ndarray:
    """Render one level of detail; returns linear RGBA float32 ``(H, W, 4)``.

    The camera frames ``frame_bounds`` (default: the high level's bounds) so
    images of different levels line up pixel for pixel, seen from ``elevation``
    degrees above the horizon (below 90).
    """
    from ..runtime import mitsuba

    mi = mitsuba("scalar_rgb")
    level = species.lod(lod)
    bounds = species.lods[0].bounds if frame_bounds is None else frame_bounds
    cam = camera_for(bounds, size, elevation)
    eye, target = cam.pop("_eye"), cam.pop("_target")
    cam["to_world"] = mi.ScalarTransform4f().look_at(origin=eye, target=target, up=[0, 1, 0])
    cam["film"] = {
        "type": "hdrfilm",
        "width": int(size[0]),
        "height": int(size[1]),
        "pixel_format": "rgba",
        "rfilter": {"type": "gaussian"},
    }
    cam["sampler"] = {"type": "independent", "sample_count": int(spp), "seed": 0}
    scene = {
        "type": "scene",
        # Every crossing of a leaf card's transparent texels costs one path vertex
        # (mask = null interaction), so depth and Russian roulette are set high
        # enough not to cut rays off inside a crown (which would lose coverage).
        "integrator": {"type": "path", "max_depth": MAX_DEPTH, "rr_depth": MAX_DEPTH, "hide_emitters": True},
        "sensor": cam,
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [0.55, 0.55, 0.55]}},
        "sun": {
            "type": "directional",
            "direction": [0.45, -0.75, -0.5],
            "irradiance": {"type": "rgb", "value": [2.2, 2.2, 2.2]},
        },
    }
    cache: dict = {}
    for i, part in enumerate(level.parts):
        scene[f"part{i}"] = {
            "type": "ply",
            "filename": str(part.path),
            "face_normals": False,
            "bsdf": part_bsdf(mi, part, cache),
        }
    img = mi.render(mi.load_dict(scene), spp=int(spp), seed=0)
    return np.array(img, dtype=np.float32).reshape(int(size[1]), int(size[0]), -1)[..., :4]


def render_preview_file(
    species, path: Path, *, lod: str = "high", size: tuple[int, int] = PREVIEW_SIZE, spp: int = PREVIEW_SPP
) -> Path:
    """Render ``species`` and write the preview PNG (sRGB, straight alpha) atomically."""
    rgba = render_lod(species, lod, size=size, spp=spp)
    a = rgba[..., 3:4]
    # Mitsuba's film holds premultiplied colour; PNG holds straight alpha.
    out = rgba.copy()
    out[..., :3] = np.where(a > 1e-6, rgba[..., :3] / np.maximum(a, 1e-6), 0.0)
    from .textures import write_texture

    return write_texture(path, out)


def alpha_coverage(rgba: np.ndarray) -> float:
    """Mean alpha of an image: the share of the frame the tree covers."""
    return float(np.clip(rgba[..., 3], 0.0, 1.0).mean())


def card_view_alpha(parts, bounds: np.ndarray, views: int, res: int, spp: int = 8) -> np.ndarray:
    """Exact coverage of ``parts`` seen orthographically along each far card's normal.

    View ``k`` looks along ``−n̂_k`` with ``n̂_k = (−sin φ_k, 0, cos φ_k)``,
    ``φ_k = πk/views``; the frame spans ``[−R, R]`` across (``R`` the largest
    |x| or |z| of ``bounds``) and the bounds' height, image row 0 at the top —
    the layout of :func:`forest.library.lod.impostor`'s atlas.  Returns
    ``(views, res, res)`` alpha rendered with Mitsuba (alpha-tested leaves included).
    """
    return card_views(parts, bounds, views, res, spp)[..., 3]


def card_view_shading(parts, bounds: np.ndarray, views: int, res: int, spp: int = 8) -> np.ndarray:
    """Straight RGB of ``parts`` under a uniform unit sky, along each far card's normal (as :func:`card_view_alpha`).

    A Lambertian surface of albedo ``a`` that sees the whole sky of radiance 1
    leaves with radiance ``a``; inside a crown it sees less of it, so the image
    is ``a·V`` (plus light scattered between leaves), ``V`` the sky's visibility:
    the crown's self-occlusion that a flat card, lit in a scene, lacks.  Returns
    ``(views, res, res, 3)`` (zeros where nothing is hit).
    """
    img = card_views(parts, bounds, views, res, spp, shaded=True)
    a = img[..., 3:4]  # the share of samples that reached a surface: RGB / a is the mean over them
    return np.where(a > 1e-4, img[..., :3] / np.maximum(a, 1e-4), 0.0).astype(np.float32)


def card_views(
    parts, bounds: np.ndarray, views: int, res: int, spp: int = 8, *, shaded: bool = False, top: bool = False
) -> np.ndarray:
    """RGBA ``(views, res, res, 4)`` of ``parts`` in the far cards' orthographic views.

    With ``top`` a view from straight above follows the ``views`` side views (``views + 1`` images): it looks
    down ``−Ŷ`` over ``x, z ∈ [−R, R]``, column ``j`` at ``x = −R + (j + ½)·2R/res`` and row ``i`` at
    ``z = −R + (i + ½)·2R/res`` — the layout of the far impostor's top tile (:func:`forest.library.lod.impostor`).

    ``shaded = False``: black opaque surfaces (RGB 0, alpha = coverage; a path
    ends at its first real hit, so depth only counts the transparent texels
    crossed on the way, and Russian roulette is off so none is cut short).
    ``shaded = True``: the parts' own materials under a constant environment of
    radiance 1 (premultiplied RGB).  Its paths bounce inside the crown, so it
    uses Russian roulette from depth 8: a camera path it ends before its first
    real hit adds nothing to RGB nor alpha, so RGB / alpha stays unbiased, but
    the alpha of a shaded render is not the coverage.
    """
    from ..runtime import mitsuba

    mi = mitsuba("scalar_rgb")
    lo, hi = np.asarray(bounds, dtype=np.float64)
    radius = float(max(np.abs(lo[[0, 2]]).max(), np.abs(hi[[0, 2]]).max(), 1e-3))
    height = float(max(hi[1] - lo[1], 1e-3))
    cy = 0.5 * (lo[1] + hi[1])
    cache: dict = {}
    black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}

    def bsdf(p):
        b = part_bsdf(mi, p, cache)
        if shaded:
            return b
        if b["type"] == "mask":
            return {"type": "mask", "opacity": b["opacity"], "material": black}
        return black

    shapes = {
        f"part{i}": {"type": "ply", "filename": str(p.path), "face_normals": False, "bsdf": bsdf(p)}
        for i, p in enumerate(parts)
    }
    # One scene (meshes, textures, acceleration structure) and one sensor per view.
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {
                "type": "path",
                "max_depth": 128 if shaded else 512,
                "rr_depth": 8 if shaded else 512,
                "hide_emitters": True,
            },
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
            **shapes,
        }
    )
    out = np.zeros((views + int(top), res, res, 4), dtype=np.float32)
    for k in range(len(out)):
        if k < views:
            phi = math.pi * k / views
            n = np.array([-math.sin(phi), 0.0, math.cos(phi)])
            eye = np.array([0.0, cy, 0.0]) + n * (4.0 * (radius + height))
            to_world = mi.ScalarTransform4f().look_at(
                origin=eye.tolist(), target=[0.0, cy, 0.0], up=[0, 1, 0]
            ) @ mi.ScalarTransform4f().scale([radius, 0.5 * height, 1.0])
        else:  # from above: image up is -z (row 0 at z = -R), image right is +x
            eye = np.array([0.0, cy + 4.0 * (radius + height), 0.0])
            to_world = mi.ScalarTransform4f().look_at(
                origin=eye.tolist(), target=[0.0, cy, 0.0], up=[0, 0, -1]
            ) @ mi.ScalarTransform4f().scale([radius, radius, 1.0])
        sensor = mi.load_dict(
            {
                "type": "orthographic",
                "to_world": to_world,
                "near_clip": 1e-3,
                "far_clip": 8.0 * (radius + height) + 1.0,
                "film": {
                    "type": "hdrfilm",
                    "width": res,
                    "height": res,
                    "pixel_format": "rgba",
                    "rfilter": {"type": "box"},
                },
                "sampler": {"type": "independent", "sample_count": spp, "seed": k},
            }
        )
        img = np.array(mi.render(scene, sensor=sensor, spp=spp, seed=k), dtype=np.float32)
        out[k] = img.reshape(res, res, -1)[..., :4]
    out[..., 3] = np.clip(out[..., 3], 0.0, 1.0)
    return out
