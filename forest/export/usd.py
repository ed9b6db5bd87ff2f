"""USD export: terrain, camera, sun and sky, and one PointInstancer per partition.

Stage layout (Y up, metres: ``upAxis = "Y"``, ``metersPerUnit = 1``)::

    /World                          Xform, the default prim
    /World/Terrain                  Mesh (points, normals, st, displayColor)
    /World/Horizon                  Mesh: the hills past the terrain's edge ([render] horizon_hills), far colour
    /World/Water                    Mesh: the ground's water (its triangles taken out of the terrain), a glossy
                                    UsdPreviewSurface of ior 1.33 over the water's colour
    /World/Camera                   Camera, time-sampled over the frames when keyed
    /World/Lights/Sun               DistantLight
    /World/Lights/Sky               DomeLight
    /World/Forest/<partition>       PointInstancer, one per partition that has trees
        Prototypes/<species>        Xform referencing <stem>_species/<species>.<ext>,
                                    with its ``lod`` variant selected

Each species is a layer of its own (``<stem>_species/<name>.usda|usdc`` beside
the stage) whose default prim carries a variant set ``lod`` with one variant per
level of the library (high, medium, low, far); each variant holds a Mesh per
part.  ``[export] usd_lod`` picks the variant the prototypes select (default:
each species' first level).

**Instances.**  Row i of a PointInstancer is a tree: ``protoIndices`` (its
species among the instancer's prototypes), ``ids`` (the InstanceSet id),
``positions``, ``orientationsf`` (float quaternions, so rotations keep float
precision; USD stores them imaginary-first) and ``orientations`` (the same in
half precision, for readers older than ``orientationsf``), ``scales`` (s, s, s) and
``primvars:displayColor`` (the colour-map tint, linear RGB, ``vertex``
interpolation = one value per instance), and — only where some tree's bark
factor differs from 1 — ``primvars:forest:barkTint`` (the bark factor f_i,
color3f, one per instance) and ``primvars:forest:barkColor`` (f_i × the
species' bark colour).  USD composes a point instancer's transform as scale,
then rotation, then translation — the InstanceSet's M = T·R·S exactly, so no
conversion is needed: the scene is already right-handed with Y up.

**Colour.**  An untinted part (bark) authors its own ``displayColor`` (its base
colour).  A tinted part (leaves) authors none, so it shows the instance's
tint, and carries its base colour as ``primvars:forest:baseColor`` for a
material that multiplies the two (the product is the reflectance the Mitsuba
render uses).  With bark factors, a bark part's material multiplies its colour
(× texture) by the instance's ``forest:barkTint`` as a leaf's does by its
tint (:func:`part_material`); without them it is an untinted part's material.

**Camera and lights.**  USD cameras look down −Z with +Y up: the camera's
transform has columns (right, up, −forward, position).  Its lens is the
config's, in millimetres: horizontalAperture = ``[camera] sensor_width``
(36 by default), verticalAperture = sensor_width · height / width, and
focalLength = (horizontalAperture / 2) / tan(fov / 2) — ``[camera]
focal_length`` itself when it is given.  focusDistance is the distance to the
target, so :mod:`forest.usd_camera` reads the same target back (fStop stays
unauthored: no depth of field).  A keyed camera is time-sampled at every
exported frame (transform, focalLength, focusDistance).  A DistantLight emits
along its local −Z; its transform turns local +Z onto d, the direction towards
the sun (:mod:`forest.lights`), so the light travels along −d.

**Texture coordinates.**  USD's st has t = 0 at the bottom of an image; the
library's uv and the terrain's map coordinates have v = 0 at the top row, so
st = (u, 1 − v).
"""

from __future__ import annotations

import errno
import math
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir, no_space
from ..camera import camera_at, frame_from_z, look_at_matrix
from ..config import Config, ConfigError
from ..config.schema import focal_length_from_fov
from ..errors import ForestError
from ..instances import InstanceSet
from ..lights import resolve_lights
from ..scene import Scene
from . import radiometry
from .common import (
    Ground,
    Horizon,
    SpeciesPlan,
    Water,
    bark_colour,
    bark_factors,
    bound_radius,
    canopy_colour,
    check_instances,
    export_frames,
    export_options,
    ground_colour,
    horizon,
    is_bark,
    leaf_cuticle,
    lod_mesh,
    look_instances,
    measured_bounds,
    part_albedo,
    partition_rows,
    species_plans,
    split_water,
    terrain_texture,
)

SUFFIXES = (".usda", ".usdc", ".usd")
#: Per-instance primvars of the bark factor f_i (written only when some f_i differs from 1): f_i itself, for
#: materials that multiply, and f_i × the species' bark colour, for those that cannot (UsdPreviewSurface).
BARK_TINT = "forest:barkTint"
BARK_COLOUR = "forest:barkColor"


@dataclass
class UsdExport:
    """What :func:`export_usd` wrote and how long it took."""

    path: Path
    species_layers: list[Path] = field(default_factory=list)
    textures: list[Path] = field(default_factory=list)
    instancers: dict[str, str] = field(default_factory=dict)  # partition → prim path
    trees: int = 0
    seconds: float = 0.0
    instance_seconds: float = 0.0

    @property
    def files(self) -> list[Path]:
        """Every file written: the stage, the species layers and the textures."""
        return [self.path] + list(self.species_layers) + list(self.textures)


def _pxr():
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

    return Gf, Sdf, Usd, UsdGeom, UsdLux, Vt


def prim_name(name: str) -> str:
    """A valid USD prim name (letters, digits, underscores; not starting with a digit)."""
    s = "".join(c if c.isalnum() or c == "_" else "_" for c in str(name))
    return s if s and not s[0].isdigit() else f"_{s}"


def gf_matrix(m: np.ndarray):
    """A column-vector 4×4 (p' = M·p) as a GfMatrix4d (USD transforms row vectors: Mᵀ)."""
    Gf = _pxr()[0]
    return Gf.Matrix4d(np.asarray(m, dtype=np.float64).T.tolist())


def usd_camera_matrix(position, target, up) -> np.ndarray:
    """Camera-to-world for USD: columns (right, up, back, position), back = −forward."""
    return look_at_matrix(position, target, up) @ np.diag([-1.0, 1.0, -1.0, 1.0])


def _set_mesh(UsdGeom, Vt, Sdf, mesh, vertices, faces, normals, uv):
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    f = np.ascontiguousarray(faces, dtype=np.int32)
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(v))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(f), 3, dtype=np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(f.ravel()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    n = np.ascontiguousarray(normals, dtype=np.float32)
    mesh.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(n))
    mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    uv = np.asarray(uv, dtype=np.float32).reshape(-1, 2)
    st = np.ascontiguousarray(np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1), dtype=np.float32)
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    pv.Set(Vt.Vec2fArray.FromNumpy(st))
    if len(v):
        mesh.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([v.min(axis=0), v.max(axis=0)])))


def _input(shader, name: str, type_name, value=None, source=None):
    """Create ``inputs:name`` on a shader and set it, or connect it to ``source`` (an output)."""
    i = shader.CreateInput(name, type_name)
    if source is not None:
        i.ConnectToSource(source)
    elif value is not None:
        i.Set(value)
    return i


def part_material(stage, path: str, part, texture: str | None, canopy=None, bark: bool = False):
    """The material of one part: a UsdPreviewSurface network, and for parts multiplied by a per-tree colour
    (tinted parts; bark parts when ``bark``) a MaterialX one.

    Untinted parts (bark without bark factors): diffuse = base colour ×
    texture.rgb (the texture is sRGB-encoded, read through ``st``, scaled by
    the linear base colour with UsdUVTexture's ``scale``), opacity = texture alpha.

    Tinted parts (leaves) — albedo = base colour × detail × tint, the model of
    :mod:`forest.render.materials`:

    * ``outputs:surface`` (every USD renderer): diffuse =
      ``UsdPrimvarReader_float3`` of ``displayColor``, the instancer's per-tree
      canopy colour (tint × base × the texture's mean detail, fallback
      ``canopy``), opacity = the texture's alpha.  UsdPreviewSurface cannot
      multiply two varying values (UsdUVTexture's ``scale`` is interface-only),
      so the texture's detail is averaged here, as Mitsuba's ``scalar_rgb`` does.
    * ``outputs:mtlx:surface`` (Karma, RenderMan, Storm with MaterialX): exact —
      ``ND_image_color4`` × base × ``ND_geompropvalue_color3`` of ``forest:tint``
      (the tint itself) into ``ND_UsdPreviewSurface_surfaceshader``, opacity =
      the image's alpha.

    Bark parts when the trees carry bark factors (``bark``) — albedo = base
    colour × detail × f_i — the same two networks: ``outputs:surface`` reads
    :data:`BARK_COLOUR` (f_i × base × the texture's mean detail, fallback the
    part's own, :func:`forest.export.common.part_albedo`), ``outputs:mtlx:surface``
    multiplies by ``ND_geompropvalue_color3`` of :data:`BARK_TINT` (f_i itself,
    default 1).
    """
    from pxr import Sdf, UsdShade

    Gf = _pxr()[0]
    T = Sdf.ValueTypeNames
    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    _input(surf, "roughness", T.Float, 0.8)
    colour = [float(c) for c in part.colour]
    tinted = bool(getattr(part, "tinted", False))
    barked = bark and is_bark(part)
    alpha = None
    if texture:
        reader = UsdShade.Shader.Define(stage, f"{path}/ST")
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        _input(reader, "varname", T.String, "st")
        tex = UsdShade.Shader.Define(stage, f"{path}/Texture")
        tex.CreateIdAttr("UsdUVTexture")
        _input(tex, "file", T.Asset, Sdf.AssetPath(texture))
        _input(tex, "sourceColorSpace", T.Token, "sRGB")
        _input(tex, "scale", T.Float4, Gf.Vec4f(*colour, 1.0))
        _input(tex, "st", T.Float2, source=reader.CreateOutput("result", T.Float2))
        rgb = tex.CreateOutput("rgb", T.Float3)
        alpha = tex.CreateOutput("a", T.Float)
        _input(surf, "opacity", T.Float, source=alpha)
        _input(surf, "opacityThreshold", T.Float, 0.5)
        if not (tinted or barked):
            _input(surf, "diffuseColor", T.Color3f, source=rgb)
    if tinted:
        _primvar_diffuse(stage, surf, f"{path}/DisplayColor", "displayColor", canopy if canopy is not None else colour)
    elif barked:
        _primvar_diffuse(stage, surf, f"{path}/BarkColor", BARK_COLOUR, part_albedo(part))
    elif not texture:
        _input(surf, "diffuseColor", T.Color3f, Gf.Vec3f(*colour))
    _cuticle(surf, part)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    factors = ([("tint", "forest:tint")] if tinted else []) + ([("bark", BARK_TINT)] if barked else [])
    if factors:
        _cuticle(_mtlx_network(stage, mat, path, colour, texture, factors), part)
    return mat


def _cuticle(surf, part) -> None:
    """A leaf's cuticle lobe on a UsdPreviewSurface (``surf``, either network): the clearcoat, UsdPreviewSurface's
    white dielectric lobe of index 1.5 (forest_path's F₀ = 0.04), of weight s and roughness √α (α = roughness²),
    with the base lobe's specular off (the specular workflow, ``specularColor`` 0), so the leaf reflects
    specularly what forest_path's lobe reflects (docs/rendering.md, "Leaf sheen").  Parts without a sheen keep
    UsdPreviewSurface's defaults."""
    from pxr import Sdf

    sheen, alpha = leaf_cuticle(part)
    if sheen <= 0:
        return
    Gf, T = _pxr()[0], Sdf.ValueTypeNames
    _input(surf, "useSpecularWorkflow", T.Int, 1)
    _input(surf, "specularColor", T.Color3f, Gf.Vec3f(0.0, 0.0, 0.0))
    _input(surf, "clearcoat", T.Float, float(sheen))
    _input(surf, "clearcoatRoughness", T.Float, round(math.sqrt(alpha), 6))


def _primvar_diffuse(stage, surf, path: str, varname: str, fallback) -> None:
    """Connect ``surf``'s diffuseColor to a ``UsdPrimvarReader_float3`` at ``path`` of ``varname`` (``fallback``
    where the primvar is absent)."""
    from pxr import Sdf, UsdShade

    Gf = _pxr()[0]
    T = Sdf.ValueTypeNames
    reader = UsdShade.Shader.Define(stage, path)
    reader.CreateIdAttr("UsdPrimvarReader_float3")
    _input(reader, "varname", T.String, varname)
    _input(reader, "fallback", T.Float3, Gf.Vec3f(*[float(c) for c in fallback]))
    _input(surf, "diffuseColor", T.Color3f, source=reader.CreateOutput("result", T.Float3))


def _mtlx_network(stage, mat, path: str, colour: list[float], texture: str | None, factors: list[tuple[str, str]]):
    """The exact network of a part multiplied by per-tree colours, in MaterialX standard-library nodes (see
    :func:`part_material`): base × image × each of ``factors`` = [(node name, primvar)], every factor read by
    an ``ND_geompropvalue_color3`` of default 1; returns its surface shader."""
    from pxr import Sdf, UsdShade

    Gf = _pxr()[0]
    T = Sdf.ValueTypeNames

    def node(name: str, node_id: str):
        sh = UsdShade.Shader.Define(stage, f"{path}/mtlx_{name}")
        sh.CreateIdAttr(node_id)
        return sh

    def factor(name: str, primvar: str):
        sh = node(name, "ND_geompropvalue_color3")
        _input(sh, "geomprop", T.String, primvar)
        _input(sh, "default", T.Color3f, Gf.Vec3f(1.0, 1.0, 1.0))
        return sh.CreateOutput("out", T.Color3f)

    surf = node("surface", "ND_UsdPreviewSurface_surfaceshader")
    _input(surf, "roughness", T.Float, 0.8)
    (first, *others) = factors
    base = Gf.Vec3f(*colour)
    first_out = factor(*first)
    albedo = node("albedo", "ND_multiply_color3")
    _input(albedo, "in1", T.Color3f, source=first_out)
    if texture:
        st = node("st", "ND_geompropvalue_vector2")
        _input(st, "geomprop", T.String, "st")
        image = node("image", "ND_image_color4")
        f = _input(image, "file", T.Asset, Sdf.AssetPath(texture))
        f.GetAttr().SetColorSpace("srgb_texture")
        _input(image, "texcoord", T.Float2, source=st.CreateOutput("out", T.Float2))
        out = image.CreateOutput("out", T.Color4f)
        rgb = node("rgb", "ND_convert_color4_color3")
        _input(rgb, "in", T.Color4f, source=out)
        detail = node("detail", "ND_multiply_color3")
        _input(detail, "in1", T.Color3f, source=rgb.CreateOutput("out", T.Color3f))
        _input(detail, "in2", T.Color3f, base)
        _input(albedo, "in2", T.Color3f, source=detail.CreateOutput("out", T.Color3f))
        a = node("alpha", "ND_extract_color4")
        _input(a, "in", T.Color4f, source=out)
        _input(a, "index", T.Int, 3)
        _input(surf, "opacity", T.Float, source=a.CreateOutput("out", T.Float))
        _input(surf, "opacityThreshold", T.Float, 0.5)
    else:
        _input(albedo, "in2", T.Color3f, base)
    result = albedo.CreateOutput("out", T.Color3f)
    for name, primvar in others:
        times = node(f"albedo_{name}", "ND_multiply_color3")
        _input(times, "in1", T.Color3f, source=result)
        _input(times, "in2", T.Color3f, source=factor(name, primvar))
        result = times.CreateOutput("out", T.Color3f)
    _input(surf, "diffuseColor", T.Color3f, source=result)
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(surf.CreateOutput("out", T.Token))
    return surf


def write_species_layer(path: Path, plan: SpeciesPlan, bark: bool = False) -> dict:
    """One species as a layer: default prim ``/<name>`` with a ``lod`` variant per level.

    Part textures are copied to ``textures/`` beside the layer (so the export
    is self-contained) and bound through :func:`part_material` (``bark``: the
    trees carry bark factors, which bark parts multiply by).  Returns
    {lod name: bound (2, 3)} of the levels written.
    """
    from pxr import UsdShade

    Gf, Sdf, Usd, UsdGeom, _UsdLux, Vt = _pxr()
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    root_path = f"/{prim_name(plan.name)}"
    root = UsdGeom.Xform.Define(stage, root_path)
    stage.SetDefaultPrim(root.GetPrim())
    Usd.ModelAPI(root.GetPrim()).SetKind("component")
    root.GetPrim().SetCustomDataByKey("forest:model", plan.model)
    vset = root.GetPrim().GetVariantSets().AddVariantSet("lod")
    bounds = {}
    lods = list(plan.species.lods)
    for lod in lods:
        meshes = lod_mesh(lod)
        bound = measured_bounds(lod, meshes)
        bounds[lod.name] = bound
        vset.AddVariant(lod.name)
        vset.SetVariantSelection(lod.name)
        with vset.GetVariantEditContext():
            geom = UsdGeom.Scope.Define(stage, f"{root_path}/Geom")
            for k, (part, m) in enumerate(meshes):
                kind = getattr(part, "kind", "surface")
                mesh = UsdGeom.Mesh.Define(stage, f"{geom.GetPath()}/{prim_name(kind)}{k}")
                _set_mesh(UsdGeom, Vt, Sdf, mesh, m.vertices, m.faces, m.normals, m.uv)
                if kind == "leaf":
                    mesh.CreateDoubleSidedAttr(True)
                pv = UsdGeom.PrimvarsAPI(mesh)
                base = Gf.Vec3f(*[float(c) for c in part.colour])
                pv.CreatePrimvar("forest:baseColor", Sdf.ValueTypeNames.Color3f, UsdGeom.Tokens.constant).Set(base)
                pv.CreatePrimvar("forest:tinted", Sdf.ValueTypeNames.Bool, UsdGeom.Tokens.constant).Set(
                    bool(getattr(part, "tinted", False))
                )
                if not getattr(part, "tinted", False):
                    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([base]))
                texture = _copy_texture(getattr(part, "texture", None), path.parent, plan.name)
                mat = part_material(
                    stage, f"{root_path}/Geom/Materials/{prim_name(kind)}{k}", part, texture, canopy_colour(lod), bark
                )
                UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
            geom.GetPrim().SetCustomDataByKey("forest:triangles", int(sum(len(m.faces) for _, m in meshes)))
            UsdGeom.ModelAPI(root.GetPrim()).SetExtentsHint(Vt.Vec3fArray.FromNumpy(bound.astype(np.float32)))
    vset.SetVariantSelection(lods[0].name)
    stage.GetRootLayer().Save()
    del stage
    return bounds


def _copy_texture(texture, layer_dir: Path, species: str) -> str | None:
    """Copy a part's texture next to the species layer; the asset path relative to the layer."""
    if not texture:
        return None
    src = Path(texture)
    if not src.is_file():
        raise ForestError(f"{src}: texture of species {species!r} not found")
    rel = f"textures/{species}_{src.name}"
    dest = layer_dir / rel
    if not dest.exists():
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(src, dest)
    return "./" + rel


def _terrain(stage, ground: Ground, colour, texture: str | None = None):
    """The terrain mesh (less its water, :func:`forest.export.common.split_water`), with ``texture`` (terrain colour
    × colour map, st = map coordinates) when given."""
    from pxr import UsdShade

    Gf, Sdf, _Usd, UsdGeom, _UsdLux, Vt = _pxr()
    mesh = UsdGeom.Mesh.Define(stage, "/World/Terrain")
    _set_mesh(UsdGeom, Vt, Sdf, mesh, ground.vertices, ground.faces, ground.normals, ground.uv)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*colour)]))
    if texture:
        part = type("TerrainPart", (), {"colour": (1.0, 1.0, 1.0), "tinted": False})()
        mat = part_material(stage, "/World/Looks/Terrain", part, texture)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return mesh


def _horizon(stage, far: Horizon):
    """The hills past the terrain's edge (:func:`forest.export.common.horizon`): a mesh in their far colour."""
    from pxr import UsdShade

    Gf, Sdf, _Usd, UsdGeom, _UsdLux, Vt = _pxr()
    mesh = UsdGeom.Mesh.Define(stage, "/World/Horizon")
    _set_mesh(UsdGeom, Vt, Sdf, mesh, far.vertices, far.faces, far.normals, far.uv)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*far.colour)]))
    part = type("HorizonPart", (), {"colour": far.colour, "tinted": False})()
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(part_material(stage, "/World/Looks/Horizon", part, None))
    return mesh


def _water(stage, water: Water):
    """The ground's water (:func:`forest.export.common.split_water`): a mesh whose UsdPreviewSurface is a glossy
    dielectric — ``diffuseColor`` the water's colour, ``ior`` 1.33, ``roughness`` from the ripples, not metallic —
    so a renderer of the stage reflects the sky and the shore in it."""
    from pxr import UsdShade

    Gf, Sdf, _Usd, UsdGeom, _UsdLux, Vt = _pxr()
    T = Sdf.ValueTypeNames
    mesh = UsdGeom.Mesh.Define(stage, "/World/Water")
    _set_mesh(UsdGeom, Vt, Sdf, mesh, water.vertices, water.faces, water.normals, water.uv)
    mesh.CreateDisplayColorPrimvar(UsdGeom.Tokens.constant).Set(Vt.Vec3fArray([Gf.Vec3f(*water.colour)]))
    mat = UsdShade.Material.Define(stage, "/World/Looks/Water")
    surf = UsdShade.Shader.Define(stage, "/World/Looks/Water/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    _input(surf, "diffuseColor", T.Color3f, Gf.Vec3f(*water.colour))
    _input(surf, "roughness", T.Float, water.roughness)
    _input(surf, "ior", T.Float, water.ior)
    _input(surf, "metallic", T.Float, 0.0)
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    return mesh


def _camera(stage, config: Config, frames: list[int]):
    Gf, _Sdf, Usd, UsdGeom, _UsdLux, _Vt = _pxr()
    cam_cfg = config.camera
    r = config.render
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateProjectionAttr(UsdGeom.Tokens.perspective)
    aperture = float(cam_cfg.sensor_width)
    cam.CreateHorizontalApertureAttr(aperture)
    cam.CreateVerticalApertureAttr(aperture * r.height / r.width)
    cam.CreateClippingRangeAttr(Gf.Vec2f(cam_cfg.near, cam_cfg.far))
    if cam_cfg.shutter > 0:
        cam.CreateShutterOpenAttr(-cam_cfg.shutter / 2)
        cam.CreateShutterCloseAttr(cam_cfg.shutter / 2)
    op = cam.AddTransformOp()
    focal = cam.CreateFocalLengthAttr()
    focus = cam.CreateFocusDistanceAttr()
    # Depth of field: USD's fStop is the f-number N (0: none) and focusDistance is in the stage's units (metres
    # here, metersPerUnit = 1); the lens radius follows from focalLength (mm) as f / (2N), as forest renders it.
    stop = cam.CreateFStopAttr() if cam_cfg.f_stop is not None else None
    animated = bool(cam_cfg.keys) and len(frames) > 1

    def focal_length(fov):
        if not cam_cfg.keys and cam_cfg.focal_length is not None:
            return float(cam_cfg.focal_length)  # as given (not through a float round trip of the fov)
        return focal_length_from_fov(fov, aperture)

    for f in frames if animated else [frames[0]]:
        s = camera_at(cam_cfg, f)
        t = Usd.TimeCode(f) if animated else Usd.TimeCode.Default()
        op.Set(gf_matrix(usd_camera_matrix(s.position, s.target, s.up)), t)
        focal.Set(focal_length(s.fov), t)
        focus.Set(float(s.focus_distance), t)  # |target − position| unless [camera] focuses elsewhere
        if stop is not None:
            stop.Set(float(s.f_stop or 0.0), t)
    return cam


def _lights(stage, config: Config, out_dir: Path):
    Gf, Sdf, _Usd, UsdGeom, UsdLux, _Vt = _pxr()
    UsdGeom.Scope.Define(stage, "/World/Lights")
    lights = resolve_lights(config)
    if lights.sun is not None:
        s = lights.sun
        sun = UsdLux.DistantLight.Define(stage, "/World/Lights/Sun")
        # unnormalised: intensity is the disk's radiance, E / (π sin²(α/2)) (forest.export.radiometry)
        sun.CreateIntensityAttr(radiometry.disk_radiance(s.irradiance, radiometry.SUN_ANGLE_DEG))
        sun.CreateNormalizeAttr(False)
        sun.CreateExposureAttr(0.0)
        sun.CreateColorAttr(Gf.Vec3f(*s.colour))
        sun.CreateAngleAttr(radiometry.SUN_ANGLE_DEG)
        # A DistantLight emits along its local −Z: turning +Z onto d makes it shine along −d.
        sun.AddTransformOp().Set(gf_matrix(frame_from_z(s.direction)))
    k = lights.sky
    if k is not None:
        sky = UsdLux.DomeLight.Define(stage, "/World/Lights/Sky")
        intensity, colour = k.dome()
        sky.CreateIntensityAttr(intensity)
        if k.kind == "envmap":
            assert k.envmap is not None  # the schema requires it for this kind
            try:
                ref = os.path.relpath(str(k.envmap), str(out_dir))
            except ValueError:
                ref = str(k.envmap)
            sky.CreateTextureFileAttr(Sdf.AssetPath(Path(ref).as_posix()))
            sky.CreateTextureFormatAttr(UsdLux.Tokens.latlong)
        else:  # a constant sky, or the dome a physical sun-sky is written as
            sky.CreateColorAttr(Gf.Vec3f(*colour))


def write_instancer(
    stage,
    path: str,
    instances: InstanceSet,
    rows: np.ndarray,
    prototypes: list[tuple[int, str]],
    lod_selection: dict[int, str],
    canopies: dict[int, np.ndarray] | None = None,
    radii: np.ndarray | None = None,
    bark: np.ndarray | None = None,
    bark_colours: dict[int, np.ndarray] | None = None,
):
    """A PointInstancer for ``rows``; ``prototypes`` = [(species index, layer path relative to the stage)].

    Per instance: ``primvars:forest:tint`` (the InstanceSet's tint) and
    ``primvars:displayColor`` = tint × the species' canopy colour
    (``canopies[species]``, :func:`canopy_colour`; 1 where absent).  With
    ``bark`` (every tree's bark factor f_i, rows as the InstanceSet's; None
    writes neither): ``primvars:forest:barkTint`` = f_i and
    ``primvars:forest:barkColor`` = f_i × the species' bark colour
    (``bark_colours[species]``, :func:`bark_colour`; 1 where absent).  ``radii``
    (per species index: the largest distance of the selected level's bound
    corners from the origin) bound the instancer's ``extent``: every tree lies
    within position ± radius × scale.
    """
    _Gf, Sdf, _Usd, UsdGeom, _UsdLux, Vt = _pxr()
    inst = UsdGeom.PointInstancer.Define(stage, path)
    UsdGeom.Scope.Define(stage, f"{path}/Prototypes")
    targets = []
    remap = np.full(len(instances.species_names), -1, dtype=np.int32)
    for k, (sp, layer) in enumerate(prototypes):
        p = stage.DefinePrim(f"{path}/Prototypes/{prim_name(Path(layer).stem)}", "Xform")
        p.GetReferences().AddReference(layer)
        p.GetVariantSets().GetVariantSet("lod").SetVariantSelection(lod_selection[sp])
        targets.append(p.GetPath())
        remap[sp] = k
    inst.CreatePrototypesRel().SetTargets(targets)
    proto = remap[instances.species[rows].astype(np.int64)]
    inst.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(proto, dtype=np.int32)))
    inst.CreateIdsAttr(Vt.Int64Array.FromNumpy(np.ascontiguousarray(instances.id[rows].astype(np.int64))))
    inst.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(instances.position[rows])))
    q = np.ascontiguousarray(instances.rotation[rows][:, [1, 2, 3, 0]])  # (w,x,y,z) → USD's (x,y,z,w)
    inst.CreateOrientationsfAttr(Vt.QuatfArray.FromNumpy(q))  # used in preference …
    inst.CreateOrientationsAttr(Vt.QuathArray.FromNumpy(q.astype(np.float16)))  # … by readers that know it
    s = instances.scale[rows]
    inst.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(np.repeat(s[:, None], 3, axis=1))))
    tint = instances.tint[rows]
    species = instances.species[rows].astype(np.int64)
    n_species = len(instances.species_names)

    def colours(name: str, values: np.ndarray) -> None:  # one colour per instance
        pv = UsdGeom.PrimvarsAPI(inst).CreatePrimvar(name, Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.vertex)
        pv.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values, dtype=np.float32)))

    colours("forest:tint", tint)
    colours("displayColor", tint * species_table(n_species, canopies)[species])
    if bark is not None:
        f = bark[rows]
        colours(BARK_TINT, f)
        colours(BARK_COLOUR, f * species_table(n_species, bark_colours)[species])
    if len(rows) and radii is not None:
        r = (radii[instances.species[rows].astype(np.int64)] * instances.scale[rows].astype(np.float32))[:, None]
        p = instances.position[rows]
        inst.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([(p - r).min(axis=0), (p + r).max(axis=0)])))
    return inst


def species_table(n: int, colours: dict[int, np.ndarray] | None) -> np.ndarray:
    """``(n, 3)`` float32: row s = ``colours[s]``, 1 for the species it does not name."""
    table = np.ones((n, 3), np.float32)
    for sp, c in (colours or {}).items():
        table[sp] = c
    return table


def export_usd(
    scene: Scene,
    path: str | Path,
    *,
    frames: str | list[int] | None = None,
    progress=None,
) -> UsdExport:
    """Write the USD stage of the scene's trees to ``path`` (``.usda``, ``.usdc`` or ``.usd`` = crate).

    The species layers go to ``<stem>_species/`` beside it.  Everything is
    written into a temporary folder and moved into place only when complete.
    """
    t0 = time.perf_counter()
    config, instances = scene.config, look_instances(scene)
    bark = bark_factors(scene)
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise ForestError(f"{path}: a USD file name must end in .usda, .usdc or .usd")
    if path.is_dir():
        raise ForestError(f"{path}: is a folder; give the stage's file name")
    opts = export_options(config)
    frame_list = export_frames(config, frames)
    check_instances(config, instances)
    plans = species_plans(scene)
    lod_selection = {}
    for plan in plans:
        names = [l.name for l in plan.species.lods]
        want = opts["usd_lod"] or names[0]
        if want not in names:
            raise ConfigError(
                config.path, "export.usd_lod", f"{want!r} is not a level of {plan.model!r} (levels: {', '.join(names)})"
            )
        lod_selection[plan.index] = want
    canopies, barks, radii = {}, {}, np.zeros(len(instances.species_names), np.float32)
    for plan in plans:
        lod = next(l for l in plan.species.lods if l.name == lod_selection[plan.index])
        c = canopy_colour(lod)
        if c is not None:
            canopies[plan.index] = c
        b = bark_colour(lod) if bark is not None else None
        if b is not None:
            barks[plan.index] = b
        radii[plan.index] = bound_radius(measured_bounds(lod, lod_mesh(lod)))
    report = progress or (lambda _f, _m="": None)
    _Gf, Sdf, Usd, UsdGeom, _UsdLux, _Vt = _pxr()
    from pxr import Tf

    ext = ".usda" if path.suffix.lower() == ".usda" else ".usdc"
    species_dir = f"{path.stem}_species"
    result = UsdExport(path=path, trees=len(instances))
    try:
        with atomic_dir(path.parent) as tmp:
            (tmp / species_dir).mkdir()
            layers = {}
            for plan in plans:
                rel = f"{species_dir}/{plan.name}{ext}"
                write_species_layer(tmp / rel, plan, bark is not None)
                layers[plan.index] = "./" + rel
                result.species_layers.append(path.parent / rel)
            result.textures = sorted(
                path.parent / p.relative_to(tmp)
                for p in (tmp / species_dir).rglob("*")
                if p.is_file() and p.parent.name == "textures"
            )
            report(0.2, "species")
            main = tmp / (path.stem + (".usda" if ext == ".usda" else path.suffix))
            layer = Sdf.Layer.CreateNew(str(main), args={"format": "usda" if ext == ".usda" else "usdc"})
            stage = Usd.Stage.Open(layer)
            UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
            UsdGeom.SetStageMetersPerUnit(stage, 1.0)
            world = UsdGeom.Xform.Define(stage, "/World")
            stage.SetDefaultPrim(world.GetPrim())
            if config.camera.keys and len(frame_list) > 1:
                stage.SetStartTimeCode(frame_list[0])
                stage.SetEndTimeCode(frame_list[-1])
            stage.SetTimeCodesPerSecond(config.camera.fps)
            stage.SetFramesPerSecond(config.camera.fps)
            grid = terrain_texture(scene)
            terrain_tex = None
            if grid is not None:
                from ..images import write_image

                write_image(tmp / f"{path.stem}_terrain.png", grid)
                terrain_tex = f"./{path.stem}_terrain.png"
                result.textures.append(path.parent / f"{path.stem}_terrain.png")
            ground, water = split_water(scene)
            _terrain(stage, ground, ground_colour(scene), terrain_tex)
            if water is not None:
                _water(stage, water)
            far = horizon(scene)
            if far is not None:
                _horizon(stage, far)
            _camera(stage, config, frame_list)
            _lights(stage, config, path.parent)
            UsdGeom.Xform.Define(stage, "/World/Forest")
            report(0.4, "instances")
            t1 = time.perf_counter()
            for _, pname, rows in partition_rows(instances):
                used = np.unique(instances.species[rows])
                protos = [(int(i), layers[int(i)]) for i in used]
                prim = f"/World/Forest/{prim_name(pname)}"
                write_instancer(stage, prim, instances, rows, protos, lod_selection, canopies, radii, bark, barks)
                result.instancers[pname] = prim
            layer.Save()
            result.instance_seconds = time.perf_counter() - t1
            del stage, layer
            report(1.0, "done")
    except (OSError, Tf.ErrorException) as e:  # disk full, permissions: one line, nothing left behind
        # USD saves through a temporary file of its own and reports a full disk by the rename it could not make
        # ("Invalid cross-device link"): the folder's free space says what happened.
        reason = os.strerror(errno.ENOSPC) if no_space(path.parent) else getattr(e, "strerror", None) or e
        raise ForestError(f"{path}: cannot write the export: {reason}") from None
    result.seconds = time.perf_counter() - t0
    return result
