"""RenderMan RIB export: the forest with its look, for RI 3.2 renderers and RenderMan 22+ (RIS).

Layout of an export folder (render from inside it: every path is relative to it)::

    objects.rib                    every species level's parts as retained objects (ObjectBegin … ObjectEnd)
    archives/<species>_<lod>.rib   one tree level: per part its material and an ObjectInstance
    textures/<species>_<name>.tif  the parts' textures (sRGB RGB detail factor, alpha = leaf-card mask)
    textures/terrain.tif           the ground's albedo grid (terrain_texture, else [ground]'s rules)
    terrain.rib                    the terrain as PointsPolygons with its textured material (its water apart,
                                   glossy in RenderMan 22+, and the hills past its edge, [render] horizon_hills,
                                   in their far colour)
    instances_<partition>.rib      per partition: one attribute block per tree
    scene_<frame>.rib              per frame: display, camera, lights, the world
    shaders/forest_surface.sl      (RI 3.2) the surface shader, RenderMan Shading Language source
    prepare.sh                     compiles the shader / makes the textures with the renderer's own tools

**Coordinate systems.**  The scene's world space (metres, Y up, right-handed)
is kept as RenderMan's world space, so every number in the instance files is
the InstanceSet's own.  RenderMan's *camera* space is left-handed (x right,
y up, z forward); the camera transform written before ``WorldBegin`` is

    W = C⁻¹,   C = [r  u  f  p]   (columns: right, up, forward, position)

with r = f × u (the right-handed "right" of a camera looking along f with up
u).  det W = −1: this single reflection is the whole conversion to RenderMan's
left-handed convention; no tree matrix, vertex or bound is mirrored.  Because
the reflection flips the handedness of world space, every object states
``Orientation "rh"``: its polygons are counter-clockwise seen from their front,
as in the library's PLY files (see :func:`forest.export.common.lod_mesh` for the
winding).

**Instancing.**  Each part of each species level used is defined once as a
retained object in ``objects.rib`` (read at the start of the world): RI 3.2
objects hold geometry only, so the object is the part's ``PointsPolygons``
with P, N and st, and its handle is a number (a string in RenderMan 22+
mode).  A tree level's archive sets each part's attributes and material and
calls ``ObjectInstance``; each tree reads its level's archive through
``Procedural "DelayedReadArchive"`` with the archive's measured bound, so a
renderer expands only the trees in view, and each expansion costs an
instance record, never a copy of the triangles.

**Instance files.**  Trees are grouped by species (in ``[[species]]`` order)
and in id order within a species; every tree is one attribute block::

    AttributeBegin
      Attribute "identifier" "string name" ["tree_<id>"]
      ConcatTransform [...16...]
      Color [r g b]
      Attribute "user" "color barktint" [r g b]
      Procedural "DelayedReadArchive" ["archives/<species>_<lod>.rib"] [bound]
    AttributeEnd

(the ``barktint`` line only where some tree's bark factor differs from 1;
see *Look*).  Nothing inside an archive sets ``identifier``, so a tree's name
is the one its block gives it.  Numbers are fixed-width (7 decimals for the
matrix, colour and bark factor, 6 for positions) so that a million trees are
formatted as one numpy byte matrix per block of :data:`CHUNK` trees and
streamed to disk (:mod:`forest.export.text`).

**Matrices.**  RenderMan transforms row vectors (p' = p·M), the InstanceSet
column vectors (p' = M·p); ``ConcatTransform`` therefore receives Mᵀ, row by
row.  M is the renderer's own tree matrix at the frame's time t = frame / fps,
wind sway included (:func:`forest.wind.tree_matrices`): with
``[wind] strength`` > 0 every frame gets its own instance files
(``instances_<partition>_<frame>.rib``), as it does when the frames' fields of
view differ and levels of detail are on (the raster areas below depend on it).

**Bounds.**  ``Procedural "DelayedReadArchive"`` and ``Detail`` take their bound
in the *current object space*, i.e. after the tree's ``ConcatTransform``: the
archive's own measured bound [xmin xmax ymin ymax zmin zmax] (the library's
``lod.bounds``, grown to contain every written vertex and rounded outwards to
1 µm), which the renderer carries through each tree's transform itself.

**Look.**  The same material model as the Mitsuba render
(:mod:`forest.render.materials`): albedo = base colour × texture RGB (decoded
from sRGB) × the tree's ``Color`` where the part is tinted × the tree's bark
factor where the part is bark; opacity = the texture's alpha; leaves lit from
behind by their translucency share.  The bark factor f_i
(:func:`forest.export.common.bark_factors`: ``[[species]] bark``'s hue/value
jitter and moss) is the user attribute ``user:barktint`` of the tree's block,
written only when some f_i differs from 1 — then bark parts' materials read it
(1 where a tree has none); otherwise neither the attribute nor the reading is
written.  RI 3.2: the ``forest_surface`` shader (``shaders/forest_surface.sl``,
compiled by ``prepare.sh``; ``"float bark" [1]`` makes it multiply by
``attribute("user:barktint")``).  RenderMan 22+: ``PxrTexture`` (linearised) ×
``PxrPrimvar`` "Cs" (tinted parts) × ``PxrAttribute`` "user:barktint" (bark
parts, default 1) through ``PxrBlend`` multiplies into a ``PxrSurface`` whose
``presence`` is the texture's alpha, double-sided for leaves.  Textures are
TIFF files (8-bit sRGB RGB + straight alpha, the library's own pixels), which
RI 3.2 renderers read; ``[export] rib_textures = "tex"`` (the default in
RenderMan 22+ mode) makes the RIB name ``.tex`` files instead, which
``prepare.sh`` makes from the TIFFs with ``txmake`` (or ``tdlmake``,
``teqser``, ``texmake``).  The terrain
takes the ground's albedo grid (the renderers' ``terrain_texture``, else
``[ground]``'s rules) through ``textures/terrain.tif``, or ``[render]
terrain_colour`` when the ground is that one material.

**Level of detail.**  When its species has several levels in the scene's LOD
plan (:mod:`forest.lod`: automatic by projected size, the default, or ``[lod]
distances``) each tree gets ``Detail`` (the
union of its levels' bounds) and, per level, ``DetailRange`` in raster pixels²
of that bound — in its block of the instance file, or, with ``[export] rib_lod =
"archive"``, in one ``archives/<species>_lod.rib`` per species that every tree
reads through a single ``Procedural``.  A band [near, far) metres becomes

    A(d) = h · w · (f / d)²,   f = (width / 2) / tan(fov / 2)

(h the bound's height, w its larger horizontal side, f the focal length in
pixels of the frame's camera fov and ``[render] width``), with a cross-fade of
± ``[export] lod_transition`` (default 10 %) of the distance at each boundary.
The bands are the plan's for a tree of scale 1; RenderMan measures each tree's
own scaled bound, so a tree of scale σ switches at σ·d — the automatic rule's
r/σ.  With the automatic rule the bands are computed for the frame's fov
(dᵢ = H·f/tᵢ), so the areas A(dᵢ) = h·w·(tᵢ/H)² do not depend on it.

**Scene files.**  ``Display`` by ``[export] rib_display`` (default ``"file"``,
the driver every RenderMan-compliant renderer has: a TIFF named after the
scene and frame); ``Format``, and ``PixelSamples`` (RI 3.2) or ``Hider`` +
``PxrPathTracer`` from ``[render]``; ``Projection "perspective"`` whose ``fov``
spans the shorter screen side (the config's spans the width: fov_ri =
2·atan(tan(fov/2)·min(W, H)/W); the fov derived from ``[camera] focal_length``
and ``sensor_width`` when those are given, noted in a ``# lens:`` comment);
``Clipping``; the camera at the frame, or —
with ``[camera] shutter`` s > 0 — ``Shutter 0 s`` and ``MotionBegin`` with
max(2, ``[render] subframes``) camera transforms.  In the world: the lights
(:func:`lights_text`, units in :mod:`forest.export.radiometry`), ``objects.rib``,
``terrain.rib`` and the instance files.

**Texture coordinates.**  The library's ``uv`` and the terrain's map
coordinates both have v = 0 on the image's top row, as RenderMan's t does, so
st = (u, v) unchanged (``PxrTexture`` gets ``invertT`` 0).
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import BinaryIO

import numpy as np

from ..atomic import atomic_dir
from ..camera import camera_at, frame_from_z, look_at_matrix
from ..config import Config, ConfigError
from ..config.schema import focal_length_from_fov
from ..errors import ForestError, ParameterError
from ..instances import InstanceSet, quaternion_to_matrix
from ..lights import resolve_lights
from ..scene import Scene
from . import radiometry
from .common import (
    Ground,
    Horizon,
    SpeciesPlan,
    Water,
    bark_factors,
    check_instances,
    export_frames,
    export_options,
    ground_colour,
    horizon,
    is_bark,
    lod_mesh,
    look_instances,
    measured_bounds,
    partition_rows,
    remove_stale,
    slug,
    species_plans,
    split_water,
    terrain_texture,
)
from .text import Field, LeftInt, RowWriter, format_numbers

CHUNK = 32768  # trees formatted per block (bounds the memory of an export)
MATRIX_DECIMALS = 7  # rotation·scale entries
POSITION_DECIMALS = 6  # metres: 1 µm
COLOUR_DECIMALS = 7
MESH_DECIMALS = 6
HEADER = b"##RenderMan RIB\n"
INFINITE_AREA = 1e38  # RenderMan's "infinitely large" detail
SHADER = "forest_surface"
#: A tree's bark factor is its user attribute ``Attribute "user" "color barktint"``; shaders read it by its full
#: name, :data:`BARK_ATTRIBUTE`.
BARK_NAME = "barktint"
BARK_ATTRIBUTE = f"user:{BARK_NAME}"

#: ``[export] rib_display`` → (display driver, image suffix).  ``file`` and ``framebuffer`` are
#: the two every RenderMan-compliant renderer has (RI 3.2, ``RiDisplay``); the others are
#: renderer families' own: ``tiff``/``openexr``/``it`` PRMan and RenderMan 22+, ``exr`` Aqsis
#: and 3Delight, ``png`` RenderMan 22+.
DISPLAYS: dict[str, tuple[str, str]] = {
    "file": ("file", ".tif"),
    "tiff": ("tiff", ".tif"),
    "openexr": ("openexr", ".exr"),
    "exr": ("exr", ".exr"),
    "png": ("png", ".png"),
    "framebuffer": ("framebuffer", ""),
    "it": ("it", ""),
}

#: Files and folders an export owns in its folder: a re-export removes those it did not write again.
OWNED = (
    "scene_*.rib",
    "instances_*.rib",
    "terrain.rib",
    "objects.rib",
    "prepare.sh",
    "archives",
    "textures",
    "shaders",
)


def shader_source() -> str:
    """The RenderMan Shading Language source of ``forest_surface`` (shipped as package data)."""
    return resources.files("forest.export").joinpath("shaders", f"{SHADER}.sl").read_text()


@dataclass
class RibExport:
    """What :func:`export_rib` wrote (paths inside ``out_dir``) and how long it took."""

    out_dir: Path
    archives: list[Path] = field(default_factory=list)
    instance_files: dict[str, Path] = field(default_factory=dict)  # partition → file (of the first frame)
    frame_instance_files: dict[int, list[Path]] = field(default_factory=dict)  # frame → the files it reads
    scenes: list[Path] = field(default_factory=list)
    textures: list[Path] = field(default_factory=list)
    shaders: list[Path] = field(default_factory=list)
    objects: Path | None = None
    terrain: Path | None = None
    prepare: Path | None = None
    trees: int = 0
    bytes: int = 0
    seconds: float = 0.0
    instance_seconds: float = 0.0
    instance_cpu_seconds: float = 0.0  # CPU time of the same (this process, all threads)

    @property
    def files(self) -> list[Path]:
        """Every RIB file written."""
        inst = sorted({p for ps in self.frame_instance_files.values() for p in ps} | set(self.instance_files.values()))
        out = list(self.archives) + inst + list(self.scenes)
        out += [p for p in (self.objects, self.terrain) if p is not None]
        return out


# ---------------------------------------------------------------------------
# small formatting helpers
# ---------------------------------------------------------------------------


def num(x: float, digits: int = 9) -> str:
    """A short decimal for header-level calls (``digits`` significant digits)."""
    x = float(x)
    if abs(x) < 1e-12:  # rounding noise of rotations (e.g. 3e-18) reads as 0
        return "0"
    s = f"{x:.{digits}g}"
    if "e" in s or "E" in s:
        m, e = s.split("e")
        s = f"{m}e{int(e)}"
    return s


def nums(values, digits: int = 9) -> str:
    """Numbers as :func:`num` writes them, space separated."""
    return " ".join(num(v, digits) for v in np.asarray(values, dtype=np.float64).ravel())


def fixed(values, decimals: int = 6) -> str:
    """Numbers with a fixed number of decimals, trailing zeros trimmed (bounds: exact to 1 µm)."""
    out = []
    for v in np.asarray(values, dtype=np.float64).ravel():
        t = f"{v:.{decimals}f}".rstrip("0").rstrip(".")
        out.append("0" if t in ("-0", "") else t)
    return " ".join(out)


def rib_matrix(m: np.ndarray) -> np.ndarray:
    """A column-vector 4×4 (p' = M·p) as RenderMan's 16 numbers (row vectors: Mᵀ row-major)."""
    return np.asarray(m, dtype=np.float64).T.ravel()


def bound6(b: np.ndarray) -> list[float]:
    """(2, 3) [min, max] → [xmin xmax ymin ymax zmin zmax], rounded outwards to 1 µm."""
    lo = np.floor(np.asarray(b[0], float) * 1e6) / 1e6
    hi = np.ceil(np.asarray(b[1], float) * 1e6) / 1e6
    return [float(v) for pair in zip(lo, hi) for v in pair]


def rib_string(s: str) -> str:
    """``s`` as a RIB string literal: double-quoted, backslashes and quotes escaped."""
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


# ---------------------------------------------------------------------------
# options
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RibOptions:
    """The ``[export]`` choices of a RIB export, resolved for its flavour."""

    renderman22: bool
    display: str  # a key of DISPLAYS
    texture_suffix: str  # ".tif" or ".tex": what the RIB names
    lod_transition: float
    lod_mode: str  # "inline" | "archive"

    @property
    def driver(self) -> str:
        """The RIB Display driver name of :attr:`display`."""
        return DISPLAYS[self.display][0]

    @property
    def image_suffix(self) -> str:
        """The file suffix of the display's image (empty for a framebuffer)."""
        return DISPLAYS[self.display][1]


def rib_options(config: Config, renderman22: bool, display: str | None = None) -> RibOptions:
    """``[export]`` keys of the RIB export; ``display`` overrides ``rib_display``."""
    e = config.export
    disp = display if display is not None else e.rib_display
    if disp not in DISPLAYS:
        message = f"unknown display {disp!r}; use one of {', '.join(DISPLAYS)}"
        if display is not None:
            raise ParameterError("display", message)
        raise ConfigError(config.path, "export.rib_display", message)
    tex = e.rib_textures or ("tex" if renderman22 else "tif")
    opts = export_options(config)
    return RibOptions(renderman22, disp, "." + tex, opts["lod_transition"], opts["rib_lod"])


# ---------------------------------------------------------------------------
# cameras and lights
# ---------------------------------------------------------------------------


def world_to_camera(position, target, up) -> np.ndarray:
    """World (right-handed, Y up) → RenderMan camera space (left-handed, +Z forward, +X right).

    Mitsuba's look-at frame has columns (left, up, forward, position); RenderMan's
    camera x axis is *right* = −left, so C = L · diag(−1, 1, 1, 1) and W = C⁻¹
    (det W = −1).
    """
    c = look_at_matrix(position, target, up) @ np.diag([-1.0, 1.0, 1.0, 1.0])
    return np.linalg.inv(c)


def ri_fov(fov_x: float, width: int, height: int) -> float:
    """RenderMan's ``fov`` spans the *shorter* screen side; the config's spans the width."""
    t = math.tan(math.radians(fov_x) / 2) * min(width, height) / width
    return math.degrees(2 * math.atan(t))


#: RenderMan's ``PxrDomeLight`` maps its latitude–longitude image with the pole along its local +Z
#: (RenderMan's documentation: a Y-up scene turns it by −90° about X).  This turns the pole onto
#: world +Y, so an ``[lights.sky] envmap`` lies as Mitsuba's ``envmap`` lays it (+Y up).
DOME_ORIENTATION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def lights_text(config: Config, renderman22: bool, envmap: str | None = None) -> str:
    """Sun and sky as RI 3.2 ``LightSource`` calls or RenderMan 22+ ``Light`` calls.

    Units (:mod:`forest.export.radiometry`): RI 3.2 ``distantlight`` intensity
    E/π and ``ambientlight`` intensity L; ``PxrDistantLight`` the radiance
    E / (π sin²(α/2)) of the 0.53° sun disk, ``PxrDomeLight`` L.  The sun shines
    along −d (d towards the sun, :mod:`forest.lights`): a
    ``distantlight`` from d to the origin, or a ``PxrDistantLight`` whose local
    +Z axis — its direction of emission — is turned onto −d.  The dome is turned
    by :data:`DOME_ORIENTATION`; ``envmap`` is the path of its image as the RIB
    names it.
    """
    lights = resolve_lights(config)
    out = []
    if lights.sun is not None:
        s = lights.sun
        d = s.direction
        if renderman22:
            out += [
                "  AttributeBegin",
                "    # sun: a disk of angular diameter a = 0.53 deg and radiance L gives E = L*pi*sin^2(a/2): L = E/(pi*sin^2(a/2))",
                f"    ConcatTransform [{nums(rib_matrix(frame_from_z(-d)))}]",
                f'    Light "PxrDistantLight" "sun" "float intensity" [{num(radiometry.disk_radiance(s.irradiance))}] '
                f'"float exposure" [0] "color lightColor" [{nums(s.colour)}] '
                f'"float angleExtent" [{num(radiometry.SUN_ANGLE_DEG)}] "int enableShadows" [1]',
                "  AttributeEnd",
            ]
        else:
            out.append(
                "  # sun: diffuse() has no 1/pi, so a distantlight of intensity E/pi gives albedo/pi * E * cos(theta)"
            )
            out.append(
                f'  LightSource "distantlight" 1 "intensity" [{num(radiometry.distantlight_intensity(s.irradiance))}] '
                f'"lightcolor" [{nums(s.colour)}] "from" [{nums(d)}] "to" [0 0 0]'
            )
    if lights.sky is not None:
        intensity, colour = lights.sky.dome()
        if renderman22:
            extra = f' "string lightColorMap" [{rib_string(envmap)}]' if envmap else ""
            out += [
                "  AttributeBegin",
                "    # sky: the dome's radiance is intensity * colour; its pole turned from +Z onto +Y",
                f"    ConcatTransform [{nums(rib_matrix(DOME_ORIENTATION))}]",
                f'    Light "PxrDomeLight" "sky" "float intensity" [{num(intensity)}] "float exposure" [0] '
                f'"color lightColor" [{nums(colour)}]{extra}',
                "  AttributeEnd",
            ]
        else:
            out.append("  # sky: ambient() gives albedo * L on open ground: intensity = the sky radiance")
            out.append(
                f'  LightSource "ambientlight" 2 "intensity" [{num(radiometry.ambient_intensity(intensity))}] '
                f'"lightcolor" [{nums(colour)}]'
            )
    return "\n".join(out) + ("\n" if out else "")


# ---------------------------------------------------------------------------
# geometry and materials
# ---------------------------------------------------------------------------


def points_polygons(vertices, faces, normals, st, indent: str = "    ") -> bytes:
    """A triangle mesh as ``PointsPolygons`` with "P", "N" (vertex) and "st" (vertex)."""
    ind = indent.encode()
    faces = np.asarray(faces, dtype=np.int64)
    nv = np.full(len(faces), 3, dtype=np.int64)
    parts = [
        ind + b"PointsPolygons [",
        format_numbers(nv, 0, per_line=40, indent=ind + b"  "),
        b"]\n",
        ind + b"  [",
        format_numbers(faces.ravel(), 0, per_line=30, indent=ind + b"   "),
        b"]\n",
        ind + b'  "P" [',
        format_numbers(np.asarray(vertices, np.float64), MESH_DECIMALS, per_line=12, indent=ind + b"   "),
        b"]\n",
        ind + b'  "N" [',
        format_numbers(np.asarray(normals, np.float64), MESH_DECIMALS, per_line=12, indent=ind + b"   "),
        b"]\n",
        ind + b'  "st" [',
        format_numbers(np.asarray(st, np.float64), MESH_DECIMALS, per_line=16, indent=ind + b"   "),
        b"]\n",
    ]
    return b"".join(parts)


def multiply_pattern(name: str, top: str, below: str) -> str:
    """A ``PxrBlend`` named ``name`` that multiplies the colour output ``top`` ("node:port") by ``below`` (its
    ``bottomRGB`` parameter: a constant colour or a reference)."""
    return (
        f'    Pattern "PxrBlend" "{name}" "int operation" [18] '
        f'"reference color topRGB" ["{top}"] "float topA" [1] {below} "float bottomA" [1]'
    )


def part_material(part, handle: str, renderman22: bool, texture: str | None, bark: bool = False) -> str:
    """The material lines of one archive part (see the module docstring, *Look*).

    ``texture`` is the part's texture as the RIB names it (relative to the export folder) or None.
    ``bark``: the trees carry bark factors, so a bark part multiplies its colour by :data:`BARK_ATTRIBUTE`.
    """
    base = nums(part.colour)
    tinted = bool(getattr(part, "tinted", False))
    barked = bark and is_bark(part)
    translucency = float(getattr(part, "translucency", 0.0) or 0.0)
    leaf = getattr(part, "kind", "surface") == "leaf"
    if not renderman22:
        params = f'"color basecolour" [{base}] "float tinted" [{int(tinted)}]'
        if barked:
            params += ' "float bark" [1]'
        if texture:
            params += f' "string texturename" [{rib_string(texture)}]'
        if translucency > 0:
            params += f' "float translucency" [{num(translucency)}]'
        lines = [] if tinted else [f"    Color [{base}]"]
        return "\n".join([*lines, f'    Surface "{SHADER}" {params}']) + "\n"
    lines = []
    below = f'"color bottomRGB" [{base}]'  # the albedo so far, as the next multiply's bottom layer
    presence = ""
    if texture:
        lines.append(
            f'    Pattern "PxrTexture" "{handle}_tex" "string filename" [{rib_string(texture)}] '
            '"int linearize" [1] "int invertT" [0] "float missingAlpha" [1]'
        )
        lines.append(multiply_pattern(f"{handle}_base", f"{handle}_tex:resultRGB", below))
        below = f'"reference color bottomRGB" ["{handle}_base:resultRGB"]'
        presence = f' "reference float presence" ["{handle}_tex:resultA"]'
    if not tinted:
        lines.append(f"    Color [{base}]")
    # Per-tree factors, each read by a pattern and multiplied in: (reader, its node, the product node, used).
    factors = [
        (f'"PxrPrimvar" "{handle}_cs" "string varname" ["Cs"] "string type" ["color"]', "cs", "colour", tinted),
        (
            f'"PxrAttribute" "{handle}_bark" "string varname" ["{BARK_ATTRIBUTE}"] '
            '"string type" ["color"] "vector defaultFloat3" [1 1 1]',
            "bark",
            "barked",
            barked,
        ),
    ]
    for reader, name, product, used in factors:
        if used:
            lines.append(f"    Pattern {reader}")
            lines.append(multiply_pattern(f"{handle}_{product}", f"{handle}_{name}:resultRGB", below))
            below = f'"reference color bottomRGB" ["{handle}_{product}:resultRGB"]'
    colour = below.replace("bottomRGB", "diffuseColor")
    extra = ""
    if translucency > 0:
        extra += f' "float diffuseTransmitGain" [{num(translucency)}] {colour.replace("diffuseColor", "diffuseTransmitColor")}'
        extra += f' "float diffuseGain" [{num(1.0 - translucency)}]'
    if leaf:
        extra += ' "int diffuseDoubleSided" [1]'
    lines.append(f'    Bxdf "PxrSurface" "{handle}" {colour}{presence}{extra}')
    return "\n".join(lines) + "\n"


class ObjectTable:
    """Retained objects, streamed to ``objects.rib``: one per (species, level, part), numbered in order."""

    def __init__(self, path: Path, renderman22: bool):
        self.path = path
        self.renderman22 = renderman22
        self.handles: dict[tuple[int, str, int], str] = {}
        self.bytes = 0
        self._fh: BinaryIO | None = None

    def define(self, key: tuple[int, str, int], name: str, mesh) -> str:
        """Write ``mesh`` as a retained object (``ObjectBegin`` … ``ObjectEnd``; the file opens on first use) and
        return its handle: ``name`` quoted for RenderMan 22, else its number.
        """
        if self._fh is None:
            self._fh = open(self.path, "wb")
            self._write(
                HEADER + b"# forest retained objects (object space: metres, Y up, base at the origin),\n"
                b"# one per species level and part, defined once and instanced by the archives (ObjectInstance)\n"
            )
        handle = rib_string(name) if self.renderman22 else str(len(self.handles) + 1)
        self.handles[key] = handle
        st = np.asarray(mesh.uv, dtype=np.float64).reshape(-1, 2)
        self._write(f"ObjectBegin {handle}  # {name}: {len(mesh.faces)} triangles\n".encode())
        self._write(points_polygons(mesh.vertices, mesh.faces, mesh.normals, st, indent="  "))
        self._write(b"ObjectEnd\n")
        return handle

    def _write(self, data: bytes) -> None:
        assert self._fh is not None
        self._fh.write(data)
        self.bytes += len(data)

    def close(self) -> bool:
        """Close the file; whether any object was written."""
        if self._fh is None:
            return False
        self._fh.close()
        return True


def archive_bytes(
    plan: SpeciesPlan, lod, meshes, bound, renderman22: bool, handles: dict, textures: dict, bark: bool = False
) -> bytes:
    """One species level: per part its attributes, material and ``ObjectInstance`` (object space, metres, Y up);
    ``bark``: bark parts multiply by the tree's bark factor (:func:`part_material`)."""
    name = f"{plan.name}_{lod.name}"
    tris = sum(len(m.faces) for _, m in meshes)
    out = [
        HEADER,
        f"# forest tree archive: species {plan.model!r}, level {lod.name}, {tris} triangles\n".encode(),
        f"# object space: metres, Y up, base at the origin; bound [{fixed(bound6(bound))}]\n".encode(),
        b"AttributeBegin\n",
        b'  Orientation "rh"\n',
    ]
    for k, (part, m) in enumerate(meshes):
        if len(m.faces) == 0:
            continue
        kind = getattr(part, "kind", "surface")
        tint_note = ", tinted" if getattr(part, "tinted", False) else ""
        tint_note += ", times the tree's bark factor" if bark and is_bark(part) else ""
        tex = textures.get(str(part.texture)) if getattr(part, "texture", None) else None
        out += [
            f"  AttributeBegin  # part {k}: {kind}{tint_note}\n".encode(),
            b"    Sides 2\n" if kind == "leaf" else b"",
            part_material(part, f"{name}_{kind}{k}", renderman22, tex, bark).encode(),
            f"    ObjectInstance {handles[(plan.index, lod.name, k)]}\n".encode(),
            b"  AttributeEnd\n",
        ]
    out.append(b"AttributeEnd\n")
    return b"".join(out)


def terrain_bytes(
    ground: Ground,
    colour,
    renderman22: bool,
    texture: str | None,
    far: Horizon | None = None,
    water: Water | None = None,
) -> bytes:
    """The terrain (``ground``: less its water, :func:`forest.export.common.split_water`): ``texture`` (terrain
    colour × colour map, st = map coordinates) or a constant colour; with ``water`` its water after it (RenderMan
    22+: a ``PxrSurface`` with a physical Fresnel specular of the water's index and roughness over its colour;
    RI 3.2: its colour), with ``far`` (:func:`forest.export.common.horizon`) the hills past its edge, in their
    constant colour."""
    out = [
        HEADER,
        f"# forest terrain: {len(ground.vertices)} vertices, {len(ground.faces)} triangles, metres, Y up\n".encode(),
        _ground_block("terrain", ground.vertices, ground.faces, ground.normals, ground.uv, colour, renderman22,
                      texture),
    ]  # fmt: skip
    if water is not None:
        out.append(f"# its water: {len(water.vertices)} vertices, {len(water.faces)} triangles\n".encode())
        glossy = (
            f'  Bxdf "PxrSurface" "water" "color diffuseColor" [{nums(water.colour)}] "int specularFresnelMode" [1] '
            f'"color specularIor" [{nums((water.ior,) * 3)}] "float specularRoughness" [{nums((water.roughness,))}]\n'
        )
        out.append(
            _ground_block("water", water.vertices, water.faces, water.normals, water.uv, water.colour, renderman22,
                          None, glossy if renderman22 else None)
        )  # fmt: skip
    if far is not None:
        out.append(f"# the hills past its edge: {len(far.vertices)} vertices, {len(far.faces)} triangles\n".encode())
        out.append(
            _ground_block("horizon", far.vertices, far.faces, far.normals, far.uv, far.colour, renderman22, None)
        )
    return b"".join(out)


def _ground_block(
    name: str, vertices, faces, normals, st, colour, renderman22: bool, texture: str | None, bxdf: str | None = None
) -> bytes:
    """One ground mesh (``terrain``, ``water`` or ``horizon``) in an attribute block: ``texture`` or a constant
    colour, or the material line ``bxdf`` as given."""
    base = (1.0, 1.0, 1.0) if texture else colour
    if bxdf is not None:
        material = bxdf
    elif renderman22:
        if texture:
            material = (
                f'  Pattern "PxrTexture" "{name}_tex" "string filename" [{rib_string(texture)}] '
                '"int linearize" [1] "int invertT" [0]\n'
                f'  Bxdf "PxrDiffuse" "{name}" "reference color diffuseColor" ["{name}_tex:resultRGB"]\n'
            )
        else:
            material = f'  Bxdf "PxrDiffuse" "{name}" "color diffuseColor" [{nums(colour)}]\n'
    else:
        tex = f' "string texturename" [{rib_string(texture)}]' if texture else ""
        material = f'  Surface "{SHADER}" "color basecolour" [{nums(base)}] "float tinted" [0]{tex}\n'
    return b"".join(
        [
            b"AttributeBegin\n",
            f'  Attribute "identifier" "string name" ["{name}"]\n'.encode(),
            b'  Orientation "rh"\n',
            f"  Color [{nums(colour)}]\n".encode(),
            material.encode(),
            points_polygons(vertices, faces, normals, st, indent="  "),
            b"AttributeEnd\n",
        ]
    )


# ---------------------------------------------------------------------------
# textures
# ---------------------------------------------------------------------------


def write_texture(dest: Path, source: Path) -> None:
    """A library texture (PNG: sRGB RGB detail, straight alpha) as a TIFF with the same 8-bit pixels."""
    from ..images import read_image, srgb_to_linear, write_image

    img = read_image(source, what="texture", unassociated=True)
    c = img.shape[2]
    rgb = img[..., :3] if c >= 3 else np.repeat(img[..., :1], 3, axis=2)
    alpha = img[..., 3:4] if c == 4 else (img[..., 1:2] if c == 2 else None)
    pixels = srgb_to_linear(rgb)  # write_image encodes to sRGB again: the stored 8-bit values come back
    if alpha is not None:
        pixels = np.concatenate([pixels, alpha], axis=2)
    attrs = {"oiio:UnassociatedAlpha": 1} if alpha is not None else None
    write_image(dest, pixels, attributes=attrs)


# ---------------------------------------------------------------------------
# level of detail
# ---------------------------------------------------------------------------


def detail_ranges(plan: SpeciesPlan, detail_bound: np.ndarray, width: int, fov: float, transition: float):
    """``DetailRange`` [minvisible lowertransition uppertransition maxvisible] per band.

    Area of the detail bound at distance d: A(d) = h·w·(f/d)² raster pixels²,
    f = (width/2)/tan(fov/2) with the frame's camera fov (module docstring).
    Band [near, far) is fully visible for areas in [A(far·(1−τ)), A(near·(1+τ))],
    fades out towards A(far·(1+τ)) and in from A(near·(1−τ)); neighbouring bands
    cross-fade over the same interval.
    """
    size = detail_bound[1] - detail_bound[0]
    area = max(float(size[1]) * max(float(size[0]), float(size[2])), 1e-12)
    f = (width / 2) / math.tan(math.radians(fov) / 2)

    def A(d):
        return area * (f / d) ** 2

    out = []
    for b in plan.bands:
        if math.isinf(b.far):
            lo_min = lo_tr = 0.0
        else:
            lo_min, lo_tr = A(b.far * (1 + transition)), A(b.far * (1 - transition))
        if b.near <= 0:
            up_tr = up_max = INFINITE_AREA
        else:
            up_tr, up_max = A(b.near * (1 + transition)), A(b.near * (1 - transition))
        out.append([lo_min, lo_tr, up_tr, up_max])
    return out


def check_transition(config: Config, transition: float, plans: list[SpeciesPlan] | None = None) -> None:
    """Refuse (``ConfigError``) a ``lod_transition`` whose cross-fades would make neighbouring LOD bands overlap.

    With ``[lod] distances`` the bands are those distances; with the automatic rule each species plan's
    (:meth:`forest.lod.LodPlan.bands`, whose ratios are the pixel thresholds' ratios).
    """
    if plans is None or config.lod.mode == "distances":
        pairs: list[tuple[SpeciesPlan | None, list[float]]] = [(None, list(config.lod.bands))]
    else:
        pairs = [(p, [b.far for b in p.bands[:-1]]) for p in plans]
    for plan, d in pairs:
        for a, b in itertools.pairwise(d):
            if b * (1 - transition) < a * (1 + transition):
                limit = (b - a) / (b + a)
                what = "" if plan is None else f" of {plan.model!r}"
                raise ConfigError(
                    config.path,
                    "export.lod_transition",
                    f"{transition:g} makes the LOD bands{what} around {a:g} m and {b:g} m overlap; "
                    f"use at most {limit:.3f}",
                )


# ---------------------------------------------------------------------------
# instance files
# ---------------------------------------------------------------------------


def procedural(path: str, bound, renderman22: bool, indent: str = "  ") -> str:
    """A delayed-read archive call for ``path`` in ``bound`` ((2, 3) [min, max]); ``Procedural2`` for RenderMan 22."""
    b = fixed(bound6(bound))
    if renderman22:
        return (
            f'{indent}Procedural2 "DelayedReadArchive2" "SimpleBound" "string filename" '
            f'[{rib_string(path)}] "float[6] bound" [{b}]'
        )
    return f'{indent}Procedural "DelayedReadArchive" [{rib_string(path)}] [{b}]'


def tree_suffixes(
    plans: list[SpeciesPlan],
    archive_paths: dict,
    bounds: dict,
    opts: RibOptions,
    width: int,
    fov: float,
    tag: str = "",
) -> tuple[dict, dict]:
    """Per species index, the constant text after a tree's ``Color`` (archive calls, LOD).

    Returns ``(suffixes, lod_archives)``: with ``lod_mode="archive"`` the
    ``Detail``/``DetailRange`` switch of a species with several levels goes to
    ``lod_archives[relative path] = bytes`` (named with ``tag`` when frames need
    their own) and each tree reads that archive with the union bound instead.
    """
    out, lod_archives = {}, {}
    r22 = opts.renderman22
    for plan in plans:
        if len(plan.bands) == 1:
            lod = plan.bands[0].lod
            lines = [procedural(archive_paths[(plan.index, lod.name)], bounds[(plan.index, lod.name)], r22)]
        else:
            bs = np.array([bounds[(plan.index, b.lod.name)] for b in plan.bands])
            detail = np.stack([bs[:, 0].min(axis=0), bs[:, 1].max(axis=0)])
            switch = [f"  Detail [{fixed(bound6(detail))}]"]
            for band, rng in zip(plan.bands, detail_ranges(plan, detail, width, fov, opts.lod_transition)):
                switch.append(f"  DetailRange [{nums(rng, 6)}]")  # raster areas: 6 digits are plenty
                switch.append(
                    procedural(archive_paths[(plan.index, band.lod.name)], bounds[(plan.index, band.lod.name)], r22)
                )
            if opts.lod_mode == "archive":
                rel = f"archives/{plan.name}_lod{tag}.rib"
                text = [
                    HEADER.decode().rstrip("\n"),
                    f"# forest level-of-detail switch: species {plan.model!r}, levels "
                    + ", ".join(f"{b.lod.name} from {b.near:g} m" for b in plan.bands),
                    f"# raster areas for a {width} px wide image and a {fov:g} degree field of view",
                    "# read by every tree: Detail and the bounds are in the tree's object space",
                    "AttributeBegin",
                    *switch,
                    "AttributeEnd",
                    "",
                ]
                lod_archives[rel] = "\n".join(text).encode()
                lines = [procedural(rel, detail, r22)]
            else:
                lines = switch
        lines.append("AttributeEnd\n")
        out[plan.index] = "\n".join(lines).encode()
    return out, lod_archives


def field_digits(instances: InstanceSet, bark: np.ndarray | None = None) -> dict:
    """Integer-part widths of the per-tree numbers, sized from the whole InstanceSet (and its bark
    factors) so the fixed-width text of a tree does not depend on how trees are split into blocks."""

    def digits(top):
        return len(str(int(math.ceil(float(top) * (1 + 1e-6) + 1e-6))))

    if len(instances) == 0:
        return {"matrix": 1, "position": 1, "colour": 1, "id": 1, "bark": 1}
    return {
        "matrix": digits(np.abs(instances.scale).max()),
        "position": digits(np.abs(instances.position).max()),
        "colour": digits(np.abs(instances.tint).max()),
        "id": len(str(int(instances.id.max()))),
        "bark": digits(np.abs(bark).max()) if bark is not None and len(bark) else 1,
    }


def block_matrices(instances: InstanceSet, rows: np.ndarray, time_s: float | None, wind) -> np.ndarray:
    """Object→world (N, 4, 4) of the trees ``rows``: T · R_sway(θ(t)) · R(q) · S(s).

    The same matrices as :func:`forest.wind.tree_matrices` (the
    renderer's sway, pivoting at the trunk base), for one block of trees; no sway
    when ``time_s`` is None.
    """
    from ..wind import sway_angles, sway_rotation

    m = np.zeros((len(rows), 4, 4), dtype=np.float64)
    m[:, :3, :3] = quaternion_to_matrix(instances.rotation[rows].astype(np.float64))
    m[:, :3, :3] *= instances.scale[rows].astype(np.float64)[:, None, None]
    if time_s is not None and wind.strength > 0 and len(rows):
        r = sway_rotation(sway_angles(instances.phase[rows], time_s, wind), wind.direction)
        m[:, :3, :3] = r @ m[:, :3, :3]
    m[:, :3, 3] = instances.position[rows].astype(np.float64)
    m[:, 3, 3] = 1.0
    return m


def write_chunk(
    out: RowWriter,
    instances: InstanceSet,
    rows: np.ndarray,
    suffix: bytes,
    widths: dict,
    time_s: float | None = None,
    wind=None,
    bark: np.ndarray | None = None,
) -> int:
    """Write the trees ``rows``: identifier, ConcatTransform (Mᵀ), Color, the bark factor (``bark``, rows as
    the InstanceSet's; none when None), then ``suffix``.

    Numbers are fixed-width (:class:`forest.export.text.RowWriter`): RIB only
    needs whitespace between tokens, and the columns line up.
    """
    if time_s is not None and wind is not None and wind.strength > 0:
        m = block_matrices(instances, rows, time_s, wind)[:, :3, :3]
    else:  # no sway: R·S straight from the quaternions (the common case, kept lean)
        m = quaternion_to_matrix(instances.rotation[rows].astype(np.float64))
        m *= instances.scale[rows].astype(np.float64)[:, None, None]
    md, pd, cd = widths["matrix"], widths["position"], widths["colour"]
    barks: list = []
    if bark is not None:
        barks = [
            f'  Attribute "user" "color {BARK_NAME}" ['.encode(),
            Field(bark[rows].astype(np.float64), COLOUR_DECIMALS, pad=True, int_digits=widths["bark"]),
            b"]\n",
        ]
    # RIB row k of Mᵀ = column k of M
    return out.write(
        [
            b'AttributeBegin\n  Attribute "identifier" "string name" ["tree_',
            LeftInt(instances.id[rows], b'"]', widths["id"]),
            b"\n  ConcatTransform [",
            Field(m[:, :, 0], MATRIX_DECIMALS, pad=True, int_digits=md),
            b" 0",
            Field(m[:, :, 1], MATRIX_DECIMALS, pad=True, int_digits=md),
            b" 0",
            Field(m[:, :, 2], MATRIX_DECIMALS, pad=True, int_digits=md),
            b" 0",
            Field(instances.position[rows].astype(np.float64), POSITION_DECIMALS, pad=True, int_digits=pd),
            b" 1]\n  Color [",
            Field(instances.tint[rows].astype(np.float64), COLOUR_DECIMALS, pad=True, int_digits=cd),
            b"]\n",
            *barks,
            suffix,
        ],
        len(rows),
    )


def write_instance_file(
    path: Path,
    instances: InstanceSet,
    rows: np.ndarray,
    partition: str,
    suffixes: dict[int, bytes],
    plans: list[SpeciesPlan],
    progress=None,
    *,
    time_s: float | None = None,
    wind=None,
    bark: np.ndarray | None = None,
) -> int:
    """Stream one partition's trees to ``path``; returns the bytes written.

    Trees are grouped by species (in the order of the config's ``[[species]]``),
    in id order within a species, and formatted in blocks of :data:`CHUNK`, so
    memory stays bounded whatever the partition's size and the archive text
    after each tree's ``Color`` is one constant per block.  ``time_s``: the
    wind's time (seconds) for the trees' sway, None for none.  ``bark``: every
    tree's bark factor (:func:`forest.export.common.bark_factors`, rows as the
    InstanceSet's), written after its ``Color``; None writes none.
    """
    names = ", ".join(f"{p.name} ({p.model})" for p in plans)
    species = instances.species[rows]
    if len(rows) and not np.isin(species, list(suffixes)).all():
        raise ForestError("instances: a tree's species has no archive")
    rows = rows[np.argsort(species, kind="stable")]
    widths = field_digits(instances, bark)
    bounds = np.searchsorted(np.sort(species), sorted(suffixes) + [np.iinfo(np.int64).max], side="left")
    written = 0
    sway = f", wind sway at t = {time_s:g} s" if time_s is not None and wind is not None and wind.strength > 0 else ""
    bark_note = (
        f"# {BARK_ATTRIBUTE} is the tree's bark factor (linear RGB) that its bark parts multiply by.\n"
        if bark is not None
        else ""
    )
    with open(path, "wb") as fh:
        head = (
            HEADER.decode() + f"# forest instances: partition {partition!r}, {len(rows)} trees; species {names}\n"
            "# world: metres, Y up, right-handed. ConcatTransform is the tree's object-to-world\n"
            f"# matrix M transposed (RenderMan transforms row vectors){sway}, Color its colour-map tint\n"
            "# (linear RGB); archive bounds are in the tree's object space.\n"
            f"{bark_note}"
            "AttributeBegin\n"
            f'Attribute "identifier" "string name" [{rib_string("partition_" + partition)}]\n'
        )
        data = head.encode()
        fh.write(data)
        written += len(data)
        done = 0
        with RowWriter(fh) as out:
            for k, sp in enumerate(sorted(suffixes)):
                block = rows[bounds[k] : bounds[k + 1]]
                for start in range(0, len(block), CHUNK):
                    r = block[start : start + CHUNK]
                    written += write_chunk(out, instances, r, suffixes[sp], widths, time_s, wind, bark)
                    done += len(r)
                    if progress:
                        progress(done / len(rows), partition)
        end = b"AttributeEnd\n"
        fh.write(end)
        written += len(end)
    return written


@dataclass(frozen=True)
class FrameGroup:
    """Frames that share instance files: the same wind pose and the same LOD raster areas."""

    frames: tuple[int, ...]
    fov: float
    time_s: float | None  # wind time, None without wind


def frame_groups(config: Config, frames: list[int], plans: list[SpeciesPlan]) -> list[FrameGroup]:
    """Group the frames whose instance files would be byte-identical.

    Instance files depend on a frame through the wind's sway (t = frame / fps,
    when ``[wind] strength`` > 0) and, when a species has several LOD bands,
    through the camera's fov (the ``DetailRange`` areas).
    """
    wind = config.wind.strength > 0
    lod = any(len(p.bands) > 1 for p in plans)
    groups: dict[tuple, list[int]] = {}
    fovs: dict[tuple, float] = {}
    for f in frames:
        fov = float(camera_at(config.camera, f).fov)
        key = (round(fov, 9) if lod else None, f if wind else None)
        groups.setdefault(key, []).append(f)
        fovs.setdefault(key, fov)
    return [FrameGroup(tuple(fs), fovs[k], (fs[0] / config.camera.fps) if wind else None) for k, fs in groups.items()]


# ---------------------------------------------------------------------------
# scene files
# ---------------------------------------------------------------------------


def scene_text(
    config: Config,
    frame: int,
    instance_files: list[str],
    opts: RibOptions,
    *,
    has_terrain: bool = True,
    has_objects: bool = True,
    envmap: str | None = None,
) -> str:
    """The RIB of one frame: display, format, sampling, camera (with motion blur), lights and its archives."""
    cam = config.camera
    r = config.render
    r22 = opts.renderman22
    image = f"{slug(config.name)}_{frame:04d}{opts.image_suffix}" if opts.image_suffix else f"{slug(config.name)}"
    out = [
        HEADER.decode().rstrip("\n"),
        f"# forest scene {config.name!r}, frame {frame}",
        "# world: metres, Y up, right-handed; the camera transform maps it to RenderMan's",
        "# left-handed camera space (x right, y up, z forward), det = -1. Render from this folder",
        "# (RI 3.2: run prepare.sh once first to compile the shader).",
        f"FrameBegin {frame}",
    ]
    if not r22:
        out.append('  Option "searchpath" "string shader" ["shaders:&"]')
    out.append(f'  Display {rib_string(image)} "{opts.driver}" "rgba"')
    out.append(f"  Format {r.width} {r.height} 1")
    if r22:
        out.append(f'  Hider "raytrace" "int minsamples" [{min(r.spp, 4)}] "int maxsamples" [{r.spp}]')
        out.append(f'  Integrator "PxrPathTracer" "integrator" "int maxPathLength" [{r.max_depth}]')
    else:
        ps = max(1, int(round(math.sqrt(r.spp))))
        out.append(f"  PixelSamples {ps} {ps}")
    state = camera_at(cam, frame)
    if cam.focal_length is not None or any(k.focal_length is not None for k in cam.keys):
        lens = focal_length_from_fov(state.fov, cam.sensor_width)
        out.append(f"  # lens: {lens:.6g} mm on a {cam.sensor_width:g} mm filmback, horizontal fov {state.fov:.6g} deg")
    out.append(
        f'  Projection "perspective" "{"float " if r22 else ""}fov" [{num(ri_fov(state.fov, r.width, r.height))}]'
    )
    out.append(f"  Clipping {num(cam.near)} {num(cam.far)}")
    if state.depth_of_field:
        # RI spec 3.2 §4.1.3: DepthOfField fstop focallength focaldistance, the last two in camera-space
        # (scene) units — metres here, so focal length f mm / 1000; lens radius f / (2·fstop) as forest's.
        lens_m = focal_length_from_fov(state.fov, cam.sensor_width) / 1000.0
        out.append(f"  DepthOfField {num(state.f_stop or 0.0)} {num(lens_m)} {num(state.focus_distance)}")
    if cam.shutter > 0:
        k = max(2, r.subframes)
        s = cam.shutter
        times = [s * i / (k - 1) for i in range(k)]
        out.append(f"  Shutter 0 {num(s)}")
        out.append(f"  MotionBegin [{nums(times)}]")
        for t in times:
            st = camera_at(cam, frame - s / 2 + t)
            out.append(f"    Transform [{nums(rib_matrix(world_to_camera(st.position, st.target, st.up)))}]")
        out.append("  MotionEnd")
    else:
        out.append(f"  Transform [{nums(rib_matrix(world_to_camera(state.position, state.target, state.up)))}]")
    out.append("  WorldBegin")
    out.append(lights_text(config, r22, envmap).rstrip("\n"))
    if instance_files and has_objects:
        out.append('  ReadArchive "objects.rib"')
    if has_terrain:
        out.append('  ReadArchive "terrain.rib"')
    for f in instance_files:
        out.append(f"  ReadArchive {rib_string(f)}")
    out.append("  WorldEnd")
    out.append("FrameEnd")
    return "\n".join(line for line in out if line) + "\n"


PREPARE = """\
#!/bin/sh
# forest RIB export: compile the surface shader and make the textures with your renderer's own
# tools, once, from this folder. The first family found on PATH is used, or set RENDERER to one
# of prman, 3delight, aqsis, pixie.
set -e
cd "$(dirname "$0")"
pick() {{ command -v "$1" >/dev/null 2>&1; }}
if [ -z "$RENDERER" ]; then
    if pick txmake; then RENDERER=prman; elif pick shaderdl; then RENDERER=3delight
    elif pick aqsl; then RENDERER=aqsis; elif pick sdrc; then RENDERER=pixie
    else echo "prepare.sh: no RenderMan shader compiler (shader, shaderdl, aqsl, sdrc) on PATH" >&2; exit 2; fi
fi
case "$RENDERER" in
    prman) SL="shader"; TX="txmake -mode clamp" ;;
    3delight) SL="shaderdl"; TX="tdlmake -mode clamp" ;;
    aqsis) SL="aqsl"; TX="teqser -wrap=clamp" ;;
    pixie) SL="sdrc"; TX="texmake -mode clamp" ;;
    *) echo "prepare.sh: unknown RENDERER $RENDERER" >&2; exit 2 ;;
esac
{shaders}{textures}echo "prepare.sh: ready for $RENDERER"
"""


def prepare_script(shaders: bool, textures: list[str], suffix: str) -> str:
    """``prepare.sh``: compile the RSL shader (RI 3.2) and turn the TIFFs into ``suffix`` textures."""
    sh = f"if [ -f shaders/{SHADER}.sl ]; then (cd shaders && $SL {SHADER}.sl); fi\n" if shaders else ""
    tx = ""
    if suffix != ".tif":
        for t in textures:
            tx += f'$TX "{t}" "{t[: -len(".tif")]}{suffix}"\n'
    return PREPARE.format(shaders=sh, textures=tx)


# ---------------------------------------------------------------------------
# the export
# ---------------------------------------------------------------------------


def export_rib(
    scene: Scene,
    out_dir: str | Path,
    *,
    renderman22: bool = False,
    frames: str | list[int] | None = None,
    display: str | None = None,
    progress=None,
) -> RibExport:
    """Write the RIB export of the scene into ``out_dir`` (see the module docstring).

    ``frames``: a spec (``"1-120"``) or list; default the camera's keyed range, or
    frame 1.  ``display`` overrides ``[export] rib_display``.  Every file is
    written to a temporary folder first and moved into ``out_dir`` only when the
    whole export succeeded; files of an earlier export into the same folder that
    this one did not write again (other partitions, frames, species) are removed.
    """
    config, instances = scene.config, look_instances(scene)
    bark = bark_factors(scene)
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ForestError(f"{out_dir}: exists and is not a folder")
    opts = rib_options(config, renderman22, display)
    frame_list = export_frames(config, frames)
    check_instances(config, instances)
    plans = species_plans(scene)
    check_transition(config, opts.lod_transition, plans)
    report = progress or (lambda _f, _m="": None)
    result = RibExport(out_dir=out_dir, trees=len(instances))
    r22 = renderman22
    try:
        with atomic_dir(out_dir) as tmp:
            if not r22:
                (tmp / "shaders").mkdir()
                (tmp / "shaders" / f"{SHADER}.sl").write_text(shader_source())
                result.shaders.append(out_dir / "shaders" / f"{SHADER}.sl")
            # textures: each library texture once, as TIFF
            textures: dict[str, str] = {}  # source path → name in the RIB
            tiffs: list[str] = []
            for plan in plans:
                for lod in plan.lods:
                    for part in lod.parts:
                        src = getattr(part, "texture", None)
                        if not src or str(src) in textures:
                            continue
                        tif = f"textures/{plan.name}_{slug(Path(src).stem)}.tif"
                        n = 2
                        while tif in tiffs:
                            tif, n = f"textures/{plan.name}_{slug(Path(src).stem)}_{n}.tif", n + 1
                        write_texture(tmp / tif, Path(src))
                        tiffs.append(tif)
                        textures[str(src)] = tif[: -len(".tif")] + opts.texture_suffix
            grid = terrain_texture(scene)
            terrain_tex = None
            if grid is not None:
                from ..images import write_image

                write_image(tmp / "textures" / "terrain.tif", grid)
                tiffs.append("textures/terrain.tif")
                terrain_tex = "textures/terrain" + opts.texture_suffix
            result.textures = [out_dir / t for t in tiffs]
            # retained objects and archives: one per species × level, written once
            objects = ObjectTable(tmp / "objects.rib", r22)
            archive_paths, bounds = {}, {}
            (tmp / "archives").mkdir()
            for plan in plans:
                for lod in plan.lods:
                    meshes = lod_mesh(lod)
                    bound = measured_bounds(lod, meshes)
                    for k, (part, m) in enumerate(meshes):
                        if len(m.faces):
                            objects.define((plan.index, lod.name, k), f"{plan.name}_{lod.name}_{part.kind}{k}", m)
                    rel = f"archives/{plan.name}_{slug(lod.name)}.rib"
                    data = archive_bytes(plan, lod, meshes, bound, r22, objects.handles, textures, bark is not None)
                    (tmp / rel).write_bytes(data)
                    archive_paths[(plan.index, lod.name)] = rel
                    bounds[(plan.index, lod.name)] = bound
                    result.archives.append(out_dir / rel)
                    result.bytes += len(data)
            if objects.close():
                result.objects = out_dir / "objects.rib"
                result.bytes += objects.bytes
            report(0.05, "archives")
            ground, water = split_water(scene)
            data = terrain_bytes(ground, ground_colour(scene), r22, terrain_tex, horizon(scene), water)
            (tmp / "terrain.rib").write_bytes(data)
            result.terrain = out_dir / "terrain.rib"
            result.bytes += len(data)
            report(0.1, "terrain")
            # instance files: one per non-empty partition and frame group
            parts = partition_rows(instances)
            groups = frame_groups(config, frame_list, plans)
            total = max(1, len(instances) * len(groups))
            done = 0
            t1, c1 = time.perf_counter(), time.process_time()
            for group in groups:
                tag = "" if len(groups) == 1 else f"_{group.frames[0]:04d}"
                # the automatic rule's boundaries scale with the frame's focal length (its DetailRange areas do not)
                group_plans = species_plans(scene, fov=group.fov) if scene.lod.mode == "pixels" else plans
                suffixes, lod_archives = tree_suffixes(
                    group_plans, archive_paths, bounds, opts, config.render.width, group.fov, tag
                )
                for rel, data in lod_archives.items():
                    (tmp / rel).write_bytes(data)
                    result.archives.append(out_dir / rel)
                    result.bytes += len(data)
                names = []
                for _, pname, rows in parts:
                    name = f"instances_{slug(pname)}{tag}.rib"

                    def sub(f, m, d=done, n=len(rows)):
                        report(0.1 + 0.85 * (d + f * n) / total, f"partition {m}")

                    result.bytes += write_instance_file(
                        tmp / name,
                        instances,
                        rows,
                        pname,
                        suffixes,
                        plans,
                        sub,
                        time_s=group.time_s,
                        wind=config.wind,
                        bark=bark,
                    )
                    result.instance_files.setdefault(pname, out_dir / name)
                    names.append(name)
                    done += len(rows)
                for f in group.frames:
                    result.frame_instance_files[f] = [out_dir / n for n in names]
            result.instance_seconds = time.perf_counter() - t1
            result.instance_cpu_seconds = time.process_time() - c1
            envmap = None
            sky = scene.lights.sky
            if sky is not None and sky.kind == "envmap" and sky.envmap is not None:
                envmap = relative_reference(sky.envmap, out_dir)
            for f in frame_list:
                rel = f"scene_{f:04d}.rib"
                files = [p.name for p in result.frame_instance_files.get(f, [])]
                text = scene_text(config, f, files, opts, has_objects=result.objects is not None, envmap=envmap)
                (tmp / rel).write_text(text)
                result.scenes.append(out_dir / rel)
                result.bytes += len(text)
            script = prepare_script(not r22, tiffs, opts.texture_suffix)
            (tmp / "prepare.sh").write_text(script)
            result.prepare = out_dir / "prepare.sh"
            remove_stale(out_dir, tmp, OWNED)
            report(1.0, "done")
    except OSError as e:  # disk full, permissions, a folder in the way: one line, nothing left
        raise ForestError(f"{out_dir}: cannot write the export: {e.strerror or e}") from None
    result.seconds = time.perf_counter() - t0
    return result


def relative_reference(path: Path, out_dir: Path) -> str:
    """``path`` as a reference from inside ``out_dir`` (relative when it can be)."""
    import os

    try:
        return Path(os.path.relpath(Path(path).resolve(), out_dir.resolve())).as_posix()
    except ValueError:
        return Path(path).as_posix()
