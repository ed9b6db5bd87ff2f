"""Scene-building pieces shared by the renderer and look-dev: camera, lights, colour grid, terrain.

Every function returns a plain Mitsuba scene-description dict (``mi.load_dict``
input), so callers can nest them, swap pieces or traverse their parameters.

Conventions: metres, Y up; the camera looks along +Z of its
frame with +X to the left (:func:`forest.camera.look_at_matrix`); the field of
view is horizontal (``fov_axis = "x"``).  The sun and sky come from
:mod:`forest.lights`, one rule for every backend; its equation (1) gives the
unit vector s towards the sun, and the ``directional`` emitter's propagation
direction is −s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ..camera import camera_at, look_at_matrix
from ..errors import ConfigError, ForestError
from ..ground import read_terrain_texture, water_colour, water_roughness, water_triangles
from ..lights import resolve_lights
from ..runtime import captured_stderr, mitsuba
from .path.arrays import mappable

if TYPE_CHECKING:
    from ..config import Config
    from ..ground import TerrainAlbedo
    from ..skirt import Hills
    from ..terrain import Terrain

#: Height margin (metres) added above and below the terrain's height range for the
#: colour-grid box.  The grid is constant along Y and clamps outside its box, so
#: any margin is exact; a wide one keeps tall trees and overhangs inside.
GRID_Y_MARGIN = 10_000.0

#: Image formats Mitsuba 3.9.1's ``Bitmap`` reads (an environment map in any other, e.g. TIFF, fails in its loader).
ENVMAP_SUFFIXES = (".exr", ".hdr", ".pfm", ".png", ".jpg", ".jpeg", ".ppm", ".tga", ".bmp")
ENVMAP_FIELD = "lights.sky.envmap"


def _is_scalar(variant: str) -> bool:
    return variant.startswith("scalar")


def transform(variant: str, matrix: npt.ArrayLike) -> object:
    """A ``ScalarTransform4f`` from a 4×4 array (scene dicts always take scalar transforms)."""
    mi = mitsuba(variant)
    return mi.ScalarTransform4f(np.asarray(matrix, dtype=np.float64))


def _rgb(value: Iterable[float]) -> dict[str, Any]:
    v = [float(x) for x in value]
    return {"type": "rgb", "value": v}


# ---------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------


def sensor_dict(
    config: Config,
    frame: float = 1.0,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    variant: str = "scalar_rgb",
    *,
    seed: int | None = None,
    rfilter: str = "box",
    sampler: str = "independent",
) -> dict[str, Any]:
    """A ``perspective`` sensor (``thinlens`` with ``[camera] f_stop``) at ``frame`` of the config's camera path.

    The camera-to-world matrix comes from :func:`forest.camera.look_at_matrix`
    of the interpolated position/target (:func:`forest.camera.camera_at`).
    ``width``/``height``/``spp`` default to ``[render]``; the sampler
    (``independent`` unless ``sampler`` names another Mitsuba sampler) is
    seeded with ``seed`` (default ``[render] seed``) so a render is
    reproducible.  The default ``box`` pixel filter keeps every sample inside
    its own pixel, so ``scalar_rgb``'s threads never add into the same pixel
    and the image is bit-identical run to run (a wider filter makes the sum
    order, hence the last bits, depend on thread timing).
    """
    cam = config.camera
    rc = config.render
    state = camera_at(cam, frame)
    m = look_at_matrix(state.position, state.target, state.up)
    # Depth of field: Mitsuba's thin lens, aperture radius r = f / (2N) m, in focus z_f m along the view axis.
    lens = (
        {"type": "thinlens", "aperture_radius": float(state.lens_radius), "focus_distance": float(state.focus_distance)}
        if state.depth_of_field
        else {"type": "perspective"}
    )
    return {
        **lens,
        "fov": float(state.fov),
        "fov_axis": "x",
        "near_clip": float(cam.near),
        "far_clip": float(cam.far),
        "to_world": transform(variant, m),
        "film": {
            "type": "hdrfilm",
            "width": int(width or rc.width),
            "height": int(height or rc.height),
            "pixel_format": "rgb",
            "component_format": "float32",
            "rfilter": {"type": rfilter},
        },
        "sampler": {
            "type": sampler,
            "sample_count": int(spp or rc.spp),
            "seed": int(rc.seed if seed is None else seed),
        },
    }


# ---------------------------------------------------------------------------
# Lights
# ---------------------------------------------------------------------------


def check_envmap(config: Config) -> None:
    """Check ``[lights.sky] envmap`` before anything is built; a :class:`ConfigError` on ``lights.sky.envmap``.

    The file must be in a format Mitsuba reads (:data:`ENVMAP_SUFFIXES`),
    decodable (through :func:`forest.images.read_image`, which also refuses
    truncated files) and hold finite, non-negative radiance: Mitsuba's
    ``envmap`` accepts NaN and negative texels and then renders NaN pixels.
    """
    sky = resolve_lights(config).sky
    if sky is None or sky.kind != "envmap":
        return
    from ..images import read_image

    path = sky.envmap
    assert path is not None  # the schema requires it for this kind
    if path.suffix.lower() not in ENVMAP_SUFFIXES:
        raise ConfigError(
            config.path,
            ENVMAP_FIELD,
            f"{path}: Mitsuba reads environment maps as {', '.join(s[1:] for s in ENVMAP_SUFFIXES)}, "
            f"not {path.suffix or 'a file without an extension'}",
        )
    try:
        img = read_image(path, what="environment map")
    except ForestError as e:
        raise ConfigError(config.path, ENVMAP_FIELD, str(e)) from None
    if float(img.min(initial=0.0)) < 0.0:
        bad = int((img < 0).sum())
        raise ConfigError(config.path, ENVMAP_FIELD, f"{path}: {bad:,} negative values; radiance must be >= 0")


def check_render_inputs(config: Config) -> None:
    """The files only a render reads (environment map, terrain texture), checked before any work.

    An environment map is also test-loaded by Mitsuba (:func:`_envmap`), which
    refuses some files OpenImageIO reads (an EXR with 2 or 5 channels).
    """
    sky = resolve_lights(config).require(config.path).sky
    if sky is not None and sky.kind == "envmap":
        _envmap(config, "scalar_rgb")
    read_terrain_texture(config)
    if config.render.denoise is True:  # "auto" turns itself off without pyoidn
        try:
            import pyoidn  # noqa: F401 - only whether it is there
        except ImportError:
            raise config.fail(
                "render.denoise", "needs Open Image Denoise: install the 'denoise' extra (pip install pyoidn)"
            ) from None


#: Environment maps already checked in this process, by (path, size, modification time).
_checked_envmaps: set[tuple[str, int, int]] = set()


def _envmap(config: Config, variant: str) -> dict[str, Any]:
    """The ``envmap`` emitter dict, checked (:func:`check_envmap`) and test-loaded by Mitsuba.

    Whatever Mitsuba's loader still refuses is reported against ``lights.sky.envmap``
    in one line, with Mitsuba's own stderr captured.
    """
    sky = resolve_lights(config).sky
    assert sky is not None and sky.envmap is not None  # called for an envmap sky only
    d = {"type": "envmap", "filename": str(sky.envmap), "scale": float(sky.intensity)}
    try:
        st = sky.envmap.stat()
        key = (str(sky.envmap.resolve()), st.st_size, st.st_mtime_ns)
    except OSError:
        key = None
    if key is not None and key in _checked_envmaps:
        return d
    check_envmap(config)
    mi = mitsuba(variant)
    failure = ""
    with captured_stderr() as noise:
        try:
            mi.load_dict(d)
        except Exception as e:  # Mitsuba raises RuntimeError with its parser's location first
            failure = str(e)
    if failure or any("error" in line.lower() for line in noise):
        text = (failure or next(line for line in noise if "error" in line.lower())).splitlines()[0]
        detail = text.split('"envmap": ')[-1].strip()
        raise ConfigError(config.path, ENVMAP_FIELD, f"{sky.envmap}: Mitsuba cannot read it: {detail}")
    if key is not None:
        _checked_envmaps.add(key)
    return d


def sun_disc_dict(
    variant: str, direction: npt.ArrayLike, irradiance: npt.ArrayLike, angular_diameter: float, distance: float
) -> dict[str, Any]:
    """A sun of finite size for Mitsuba's integrators: a ``disk`` area light far away toward the sun.

    Mitsuba 3.9.1's ``directional`` emitter is a point on the sky (razor-sharp
    shadows).  A disk of radius R = D·tan α at distance D, facing the scene,
    subtends the sun's angular radius α; its radiance L = E / (π sin²α),
    sin α = R / √(D² + R²), gives irradiance E on a surface facing it — the
    disc sun of forest_path (``forest.render.path.emitters.DiscSun``).  D lies
    beyond the ground's skirt; the camera's far clip may hide the disc itself
    from camera rays, never from shadow rays.
    """
    s = np.asarray(direction, np.float64)
    s = s / np.linalg.norm(s)
    alpha = math.radians(float(angular_diameter)) / 2.0
    radius = float(distance) * math.tan(alpha)
    sin2 = radius**2 / (float(distance) ** 2 + radius**2)
    radiance = np.asarray(irradiance, np.float64) / (math.pi * sin2)
    from ..camera import frame_from_z

    m = np.eye(4)
    m[:3, :3] = frame_from_z(-s)[:3, :3] * radius  # the disk's +Z normal faces the scene
    m[:3, 3] = s * float(distance)
    return {
        "type": "disk",
        "to_world": transform(variant, m),
        "emitter": {"type": "area", "radiance": _rgb(radiance)},
    }


#: Distance of the scalar renderer's sun disk, metres (beyond any skirt: :mod:`forest.skirt`).
SUN_DISTANCE = 1.0e6


def emitter_dicts(config: Config, variant: str, *, disc_sun: bool = False) -> dict[str, dict[str, Any]]:
    """Emitters for the config's lights (:func:`forest.lights.resolve_lights`): ``{"sun": directional | disk,
    "sky": constant | envmap | sunsky}``.

    * sun — irradiance ``irradiance · colour`` (W/m² per RGB channel on a
      surface facing it), shining along −s; present when the sun is on.
      ``disc_sun``: a disc of ``forest.render.path.inputs.SUN_ANGULAR_DIAMETER``
      (:func:`sun_disc_dict`, soft shadows) instead of Mitsuba's point-like ``directional``.
    * sky — ``constant`` radiance ``radiance · colour``; or an ``envmap``
      (latitude–longitude, +Y up) scaled by ``scale``; or Mitsuba's ``sunsky``
      (Hosek–Wilkie sky + sun, Z-up in Mitsuba, rotated here to Y-up) pointed
      at its sun, which it then replaces; its sun and sky are scaled by one
      factor so its sun sends that sun's irradiance
      (:func:`forest.render.path.emitters.sunsky_scale`), times ``sunsky.scale``.

    An environment map is checked and test-loaded here (Mitsuba has a strict
    load), so a bad one fails here naming ``lights.sky.envmap``, not inside
    ``mi.load_dict`` with a traceback.
    """
    from .path.emitters import sunsky_dict, sunsky_scale
    from .path.inputs import SUN_ANGULAR_DIAMETER

    mi = mitsuba(variant)
    lights = resolve_lights(config).require(config.path)
    if lights.clouds is not None:
        import warnings

        from ..errors import ForestWarning

        warnings.warn(f"[lights.clouds]: not rendered in {variant} (Mitsuba's own integrator has no cloud layer; "
                      "forest_path renders it): the sky is clear", ForestWarning, stacklevel=2)  # fmt: skip
    sky = lights.sky
    if sky is not None and sky.kind == "envmap" and sky.background != "map":
        import warnings

        from ..errors import ForestWarning

        warnings.warn(f"[lights.sky] background = {sky.background!r}: not rendered in {variant} (Mitsuba's own "
                      "integrator cannot show camera rays another sky; forest_path renders it): the camera sees "
                      "the map", ForestWarning, stacklevel=2)  # fmt: skip
    if sky is not None and sky.kind == "sunsky":
        assert sky.sun is not None  # resolve_lights always points a sun-sky at a sun
        d = sky.sun.direction
        k = sunsky_scale(mi, d, sky.turbidity, sky.albedo, float(sky.sun.irradiance)) * float(sky.intensity)
        return {"sky": sunsky_dict(mi, d, sky.turbidity, sky.albedo, sun_scale=k, sky_scale=k)}
    out: dict[str, dict[str, Any]] = {}
    sun = lights.sun
    if sun is not None:
        s = sun.direction
        if disc_sun:
            out["sun"] = sun_disc_dict(variant, s, sun.rgb, SUN_ANGULAR_DIAMETER, SUN_DISTANCE)
        else:
            out["sun"] = {"type": "directional", "direction": [float(x) for x in -s], "irradiance": _rgb(sun.rgb)}
    if sky is not None:
        out["sky"] = (
            _envmap(config, variant) if sky.kind == "envmap" else {"type": "constant", "radiance": _rgb(sky.radiance)}
        )
    return out


# ---------------------------------------------------------------------------
# Colour grid: a map evaluated at each hit's world position
# ---------------------------------------------------------------------------


def grid_to_world(extent: Sequence[float], height_range: Sequence[float]) -> np.ndarray:
    """4×4 matrix mapping the grid's unit cube onto the terrain box.

    Local (x, y, z) ∈ [0, 1]³ → world (xmin + x·(xmax−xmin), y0 + y·(y1−y0),
    zmin + z·(zmax−zmin)), with y0/y1 the height range widened by
    :data:`GRID_Y_MARGIN`.
    """
    xmin, zmin, xmax, zmax = (float(v) for v in extent)
    y0 = float(height_range[0]) - GRID_Y_MARGIN
    y1 = float(height_range[1]) + GRID_Y_MARGIN
    m = np.eye(4)
    m[0, 0], m[1, 1], m[2, 2] = max(xmax - xmin, 1e-9), y1 - y0, max(zmax - zmin, 1e-9)
    m[:3, 3] = (xmin, y0, zmin)
    return m


def colour_grid_texture(
    grid: npt.ArrayLike,
    extent: Sequence[float],
    height_range: Sequence[float],
    variant: str,
    *,
    filter_type: str = "trilinear",
) -> dict[str, Any]:
    """A ``volume`` texture over a ``gridvolume`` laid on the terrain's box.

    ``grid`` is (H, W, 3) linear RGB in the map convention (row i → +Z with
    row 0 at ``zmin``, column j → +X).  Mitsuba's grid layout is (z, y, x, c),
    so the data is ``grid[:, None, :, :]`` — one cell along Y, which the
    texture clamps, making the colour independent of height.  Texel centres
    sit at pixel centres, x = xmin + (j + ½)·Δx, z = zmin + (i + ½)·Δz, as in
    the map convention; ``trilinear`` interpolates between them, ``nearest``
    returns the pixel's own value.  Lookups outside the box clamp to the edge.

    Every shape using this texture as a reflectance takes its colour from the
    map at the hit's *world* position, so all instances of one shapegroup are
    tinted where they stand.  In JIT variants the data is a differentiable
    ``TensorXf`` (parameter ``….volume.data``).
    """
    mi = mitsuba(variant)
    g = np.asarray(grid, dtype=np.float32)
    if g.ndim != 3 or g.shape[2] != 3 or g.shape[0] < 1 or g.shape[1] < 1:
        raise ForestError(f"colour grid must be (H, W, 3), got shape {g.shape}")
    if not np.isfinite(g).all():
        raise ForestError("colour grid contains NaN or infinite values")
    data = np.ascontiguousarray(g[:, None, :, :])
    vol = {
        "type": "gridvolume",
        "filter_type": filter_type,
        "wrap_mode": "clamp",
        "to_world": transform(variant, grid_to_world(extent, height_range)),
    }
    if _is_scalar(variant):
        vol["grid"] = mi.VolumeGrid(data)
    else:
        vol["data"] = mi.TensorXf(mappable(data))
    return {"type": "volume", "volume": vol}


# ---------------------------------------------------------------------------
# Terrain
# ---------------------------------------------------------------------------


def terrain_mesh(
    terrain: Terrain,
    variant: str,
    bsdf: dict[str, Any] | None = None,
    name: str = "terrain",
    *,
    skirt: float = 0.0,
    hills: Hills | None = None,
    faces: np.ndarray | None = None,
    sea: bool | None = None,
) -> Any:
    """The terrain as a Mitsuba ``Mesh`` object (positions, faces, smooth normals, uv) with ``bsdf``.

    ``skirt`` > 0 adds the ground that carries it to that radius (:func:`forest.skirt.skirt_mesh`), with
    ``hills`` on it (None: a level plain).  ``faces``: a subset of the terrain's triangles (default: all).
    ``sea``: of the skirt, only the faces its still water covers (True) or only the others (False)
    (:func:`forest.skirt.wet_faces`; None: all of them).
    """
    mi = mitsuba(variant)
    v = np.asarray(terrain.vertices, dtype=np.float32)
    f = np.asarray(terrain.faces if faces is None else faces, dtype=np.uint32)
    n = np.asarray(terrain.vertex_normals, dtype=np.float32)
    uv = np.asarray(terrain.uv, dtype=np.float32)
    if skirt > 0:
        from ..skirt import skirt_mesh

        sk = skirt_mesh(terrain, skirt, hills)
        if sk is not None and sea is not None and terrain.water is not None:
            from ..skirt import sea_side

            sk = sea_side(sk, float(terrain.water[0]), sea)
        if sk is not None:
            xmin, zmin, xmax, zmax = terrain.extent
            sk_uv = np.stack(
                [
                    (sk.vertices[:, 0] - xmin) / max(xmax - xmin, 1e-9),
                    (sk.vertices[:, 2] - zmin) / max(zmax - zmin, 1e-9),
                ],
                axis=1,
            ).astype(np.float32)
            f = np.concatenate([f, sk.faces + np.uint32(len(v))])
            v, n, uv = np.concatenate([v, sk.vertices]), np.concatenate([n, sk.normals]), np.concatenate([uv, sk_uv])
    props = mi.Properties()
    if bsdf is not None:
        props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh(
        name, vertex_count=len(v), face_count=len(f), has_vertex_normals=True, has_vertex_texcoords=True, props=props
    )
    params = mi.traverse(mesh)
    conv: Callable[[np.ndarray], Any] = (
        (lambda a: a.ravel()) if _is_scalar(variant) else (lambda a: mi.Float(mappable(a.ravel())))
    )
    params["vertex_positions"] = conv(v)
    params["faces"] = f.ravel() if _is_scalar(variant) else mi.UInt32(mappable(f.ravel()))
    params["vertex_normals"] = conv(n)
    params["vertex_texcoords"] = conv(uv)
    params.update()
    return mesh


def terrain_reflectance(
    albedo: TerrainAlbedo, terrain: Terrain, variant: str, *, fade: bool = False, tint: npt.ArrayLike | None = None
) -> dict[str, Any]:
    """The terrain's reflectance: the Scene's albedo grid × its fitted ground tint.

    ``albedo`` is the Scene's ``terrain_albedo`` (:class:`forest.ground.TerrainAlbedo`,
    the one place the ground is resolved: ``[render] terrain_texture``, else
    ``terrain_colour``, else the ``[ground]`` rules), an (H, W, 3) linear grid
    over its extent, evaluated by world position like the colour grid; its
    tileable detail texture, of mean 1, is left out here — the scalar renderer
    runs no Python texture plugin per sample (:mod:`forest.render.materials`).
    ``tint``: the Scene's fitted ``ground_tint`` (RGB), or None.  ``fade``: the
    grid fades past the terrain's edge to the far landscape's albedo the Scene
    computed (:func:`forest.skirt.far_colour`, :func:`forest.skirt.fade_beyond_edge`;
    for the skirt that carries the ground to the horizon), times the tint like
    the grid — the rule forest_path uses too (:mod:`forest.render.path.ground`).
    """
    from ..skirt import fade_beyond_edge, far_colour

    grid = np.asarray(albedo.rgb, np.float32)
    extent = tuple(float(v) for v in albedo.extent)
    far = far_colour(albedo)
    if tint is not None and not np.all(np.asarray(tint) == 1.0):
        grid = (grid * np.asarray(tint, np.float32).reshape(3)).astype(np.float32)
        far = (far * np.asarray(tint, np.float32).reshape(3)).astype(np.float32)
    if fade:
        grid, extent = fade_beyond_edge(grid, extent, far)
    if grid.shape[0] * grid.shape[1] == 1:
        return _rgb(grid[0, 0])  # one material (and the same far away): a constant, no texture lookup per hit
    return colour_grid_texture(grid, extent, terrain.height_range, variant)


def terrain_dict(
    albedo: TerrainAlbedo,
    terrain: Terrain,
    variant: str,
    *,
    skirt: float = 0.0,
    hills: Hills | None = None,
    tint: npt.ArrayLike | None = None,
) -> Any:
    """The terrain as a scene child: a ``Mesh`` object with a diffuse BSDF, less the ground's water (drawn apart,
    :func:`ground_dicts`).

    The returned object goes into a scene dict like any shape dict
    (``scene["terrain"] = terrain_dict(...)``).  Reflectance: see
    :func:`terrain_reflectance` (``albedo``: the Scene's ``terrain_albedo``;
    ``tint``: the Scene's ``ground_tint``); ``skirt``, ``hills``: see :func:`terrain_mesh`.
    """
    return _terrain_obj(albedo, terrain, variant, water_triangles(terrain, albedo), skirt, hills, tint)


def ground_dicts(
    albedo: TerrainAlbedo,
    terrain: Terrain,
    variant: str,
    *,
    skirt: float = 0.0,
    hills: Hills | None = None,
    tint: npt.ArrayLike | None = None,
    ripple: float = 0.0,
) -> tuple[Any, Any | None]:
    """The terrain (:func:`terrain_dict`) and the ground's water as a scene child of its own, or None without
    water: the terrain's triangles of :func:`forest.ground.water_triangles` with Mitsuba's ``plastic`` BSDF — a
    smooth dielectric interface of index 1.33 over a diffuse base of the water's colour
    (:func:`forest.ground.water_colour` × ``tint``; the exports' colour too), the Fresnel mirror over the bed that
    forest_path shades per hit (:mod:`forest.render.path.materials`) — or ``roughplastic`` (GGX, α = tan
    ``ripple``, :func:`forest.ground.water_roughness` squared) when it ripples.  Which triangles are water is
    found once for both.  With the skirt (``skirt`` > 0) and still water at the terrain's edge, the skirt's sea
    (:func:`forest.skirt.wet_faces`) is water too (:mod:`forest.skirt`, "The sea")."""
    from ..config.schema import WATER_IOR

    wet = water_triangles(terrain, albedo)
    ground = _terrain_obj(albedo, terrain, variant, wet, skirt, hills, tint)
    sea = _skirt_sea(terrain, skirt)
    if wet is None and not sea:
        return ground, None
    colour = water_colour(albedo)
    if tint is not None:
        colour = colour * np.asarray(tint, np.float64).reshape(3)
    bsdf: dict[str, Any] = {"int_ior": WATER_IOR, "ext_ior": 1.0, "diffuse_reflectance": _rgb(colour)}
    if ripple > 0.0:
        bsdf.update(type="roughplastic", distribution="ggx", alpha=water_roughness(ripple) ** 2)
    else:
        bsdf["type"] = "plastic"
    faces = terrain.faces[wet] if wet is not None else np.zeros((0, 3), np.int64)
    if not sea:
        return ground, terrain_mesh(terrain, variant, bsdf, name="water", faces=faces)
    return ground, terrain_mesh(terrain, variant, bsdf, name="water", faces=faces, skirt=skirt, hills=hills, sea=True)


def _skirt_sea(terrain: Terrain, skirt: float) -> bool:
    """Whether the skirt out to ``skirt`` metres (0: none) carries still water past the terrain's edge."""
    from ..skirt import sea_at_edge

    return skirt > 0 and terrain.water is not None and sea_at_edge(terrain) is not None


def _terrain_obj(
    albedo: TerrainAlbedo,
    terrain: Terrain,
    variant: str,
    wet: np.ndarray | None,
    skirt: float,
    hills: Hills | None,
    tint: npt.ArrayLike | None,
) -> Any:
    """The terrain's diffuse mesh without the triangles ``wet`` marks (all of them when None), and its skirt
    without the sea's (:func:`ground_dicts` draws those as water)."""
    reflectance = terrain_reflectance(albedo, terrain, variant, fade=skirt > 0, tint=tint)
    bsdf = {"type": "diffuse", "reflectance": reflectance}
    faces = None if wet is None else terrain.faces[~wet]
    sea = False if _skirt_sea(terrain, skirt) else None
    return terrain_mesh(terrain, variant, bsdf, skirt=skirt, hills=hills, faces=faces, sea=sea)
