"""RenderMan RIB export: archives per species × level, instance files per partition, a scene per frame.

Layout of an export folder (render from inside it: every path is relative to it)::

    archives/<species>_<lod>.rib   one tree level as PointsPolygons with P, N and st
    terrain.rib                    the terrain as PointsPolygons
    instances_<partition>.rib      per partition: one attribute block per tree
    scene_<frame>.rib              per frame: options, camera, lights, world
    shaders/forest_tint.sl         (RI 3.2 mode) the surface shader tinted parts use

**Coordinate systems.**  The scene's world space (metres, Y up, right-handed)
is kept as RenderMan's world space, so every number in the instance files is
the InstanceSet's own.  RenderMan's *camera* space is left-handed (x right,
y up, z forward); the camera transform written before ``WorldBegin`` is

    W = C⁻¹,   C = [r  u  f  p]   (columns: right, up, forward, position)

with r = f × u (the right-handed "right" of a camera looking along f with up
u).  det W = −1: this single reflection is the whole conversion to RenderMan's
left-handed convention; no tree matrix, vertex or bound is mirrored.  Because
the reflection flips the handedness of world space, every archive states
``Orientation "rh"``: its polygons are counter-clockwise seen from their front,
as in the library's PLY files.

**Instance files.**  Trees are grouped by species (in ``[[species]]`` order)
and in id order within a species; every tree is one attribute block::

    AttributeBegin
      Attribute "identifier" "string name" ["tree_<id>"]
      ConcatTransform [...16...]
      Color [r g b]
      Procedural "DelayedReadArchive" ["archives/<species>_<lod>.rib"] [bound]
    AttributeEnd

Its numbers are fixed-width (7 decimals for the matrix and colour, 6 for
positions) so that a million trees are formatted as one numpy byte matrix per
block of :data:`CHUNK` trees and streamed to disk (:mod:`forest.export.text`).

**Matrices.**  RenderMan transforms row vectors (p' = p·M), the InstanceSet
column vectors (p' = M·p); ``ConcatTransform`` therefore receives Mᵀ, row by
row: ``[m00 m10 m20 0  m01 m11 m21 0  m02 m12 m22 0  tx ty tz 1]``.

**Bounds.**  ``Procedural "DelayedReadArchive"`` and ``Detail`` take their bound
in the *current object space*, i.e. after the tree's ``ConcatTransform``: the
archive's own measured bound [xmin xmax ymin ymax zmin zmax] (the library's
``lod.bounds``, grown to contain every written vertex and rounded outwards to
1 µm), which the renderer carries through each tree's transform itself.

**Colour.**  Each tree's ``Color`` is its colour-map tint (linear RGB, 1 =
untinted).  In an archive, untinted parts set their own ``Color``; tinted
parts keep the tree's and multiply it by their base colour in the shader
(``forest_tint`` in RI 3.2 mode; ``PxrPrimvar`` "Cs" × ``PxrBlend`` multiply
into ``PxrSurface`` in RenderMan 22+ mode).

**Level of detail.**  With ``[lod] distances`` each tree gets ``Detail`` (the
union of its levels' bounds) and, per level, ``DetailRange`` in raster pixels²
of that bound — in its block of the instance file, or, with ``[export] rib_lod =
"archive"``, in one ``archives/<species>_lod.rib`` per species that every tree
reads through a single ``Procedural`` (the same switch, evaluated in the tree's
object space; a third of the bytes).  A band [near, far) metres becomes

    A(d) = h · w · (f / d)²,   f = (width / 2) / tan(fov / 2)

(h the bound's height, w its larger horizontal side, f the focal length in
pixels of ``[camera] fov``/``[render] width``), with a cross-fade of
± ``[export] lod_transition`` (default 10 %) of the distance at each boundary.

**Scene files.**  ``Format`` and ``PixelSamples``/``Hider`` from ``[render]``;
``Projection "perspective"`` whose ``fov`` spans the shorter screen side (the
config's spans the width: fov_ri = 2·atan(tan(fov/2)·min(W, H)/W));
``Clipping`` near/far; the camera at the frame, or — with ``[camera] shutter``
s > 0 — ``Shutter 0 s`` and ``MotionBegin`` with max(2, ``[render] subframes``)
camera transforms sampled evenly from frame − s/2 to frame + s/2 (times in
frames).  In the world: the sun (see :func:`forest.export.common.sun_direction`)
as ``distantlight`` from d towards the origin or a ``PxrDistantLight`` turned
so its +Z (its emission) is −d, omitted at or below the horizon as in the
render; the sky as ``ambientlight`` or ``PxrDomeLight`` (an envmap feeds the
dome's ``lightColorMap``); then ``terrain.rib`` and the instance files.

**Texture coordinates.**  The library's ``uv`` and the terrain's map
coordinates both have v = 0 on the image's top row, as RenderMan's t does, so
st = (u, v) unchanged.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_dir
from ..camera import camera_at, frame_from_z, look_at_matrix
from ..config import Config, ConfigError
from ..errors import ForestError
from ..instances import InstanceSet, quaternion_to_matrix
from ..scene import Scene
from .common import (
    SpeciesPlan,
    check_instances,
    export_frames,
    export_options,
    lod_mesh,
    measured_bounds,
    partition_rows,
    slug,
    species_plans,
    sun_direction,
)
from .text import Field, LeftInt, RowWriter, format_numbers

CHUNK = 32768  # trees formatted per block (bounds the memory of an export)
MATRIX_DECIMALS = 7  # rotation·scale entries
POSITION_DECIMALS = 6  # metres: 1 µm
COLOUR_DECIMALS = 7
MESH_DECIMALS = 6
HEADER = b"##RenderMan RIB\n"
INFINITE_AREA = 1e38  # RenderMan's "infinitely large" detail

TINT_SHADER = """\
/* forest_tint: Cs (the tree's colour-map tint) times the part's base colour, diffuse.
   Compile with your renderer's shader compiler, e.g. `shader forest_tint.sl`. */
surface forest_tint(float Ka = 1, Kd = 0.8; color basecolour = 1)
{
    normal Nf = faceforward(normalize(N), I);
    Oi = Os;
    Ci = Os * Cs * basecolour * (Ka * ambient() + Kd * diffuse(Nf));
}
"""


@dataclass
class RibExport:
    """What :func:`export_rib` wrote (paths inside ``out_dir``) and how long it took."""

    out_dir: Path
    archives: list[Path] = field(default_factory=list)
    instance_files: dict[str, Path] = field(default_factory=dict)  # partition → file
    scenes: list[Path] = field(default_factory=list)
    terrain: Path | None = None
    trees: int = 0
    bytes: int = 0
    seconds: float = 0.0
    instance_seconds: float = 0.0
    instance_cpu_seconds: float = 0.0  # CPU time of the same (this process, all threads)

    @property
    def files(self) -> list[Path]:
        out = list(self.archives) + list(self.instance_files.values()) + list(self.scenes)
        return out + ([self.terrain] if self.terrain else [])


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
    return '"' + str(s).replace("\\", "\\\\").replace('"', '\\"') + '"'


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


def lights_text(config: Config, renderman22: bool) -> str:
    """Sun and sky as RI 3.2 ``LightSource`` calls or RenderMan 22+ ``Light`` calls.

    The sun shines along −d (d from :func:`forest.export.common.sun_direction`):
    a ``distantlight`` from d to the origin, or a ``PxrDistantLight`` whose
    local +Z axis — its direction of emission — is turned onto −d.
    """
    lights = config.lights
    out = []
    if lights.sun is not None and lights.sun.elevation > 0 and lights.sun.irradiance > 0:
        s = lights.sun  # (a sun at or below the horizon lights nothing, as in the render)
        d = sun_direction(s)
        if renderman22:
            out += [
                "  AttributeBegin",
                '    Attribute "identifier" "string name" ["sun"]',
                f"    ConcatTransform [{nums(rib_matrix(frame_from_z(-d)))}]",
                f'    Light "PxrDistantLight" "sun" "float intensity" [{num(s.irradiance)}] '
                f'"color lightColor" [{nums(s.colour)}] "float angleExtent" [0.53]',
                "  AttributeEnd",
            ]
        else:
            out.append(
                f'  LightSource "distantlight" 1 "intensity" [{num(s.irradiance)}] '
                f'"lightcolor" [{nums(s.colour)}] "from" [{nums(d)}] "to" [0 0 0]'
            )
    if lights.sky is not None:
        k = lights.sky
        if k.kind == "constant":
            intensity, colour = k.radiance, k.colour
        elif k.kind == "envmap":
            intensity, colour = k.scale, (1.0, 1.0, 1.0)
        else:  # physical sun-sky: a neutral blue dome stands in
            intensity, colour = 0.35 * k.sunsky.scale, (0.6, 0.75, 1.0)
        if renderman22:
            extra = f' "string lightColorMap" [{rib_string(k.envmap)}]' if k.kind == "envmap" else ""
            out += [
                "  AttributeBegin",
                '    Attribute "identifier" "string name" ["sky"]',
                f'    Light "PxrDomeLight" "sky" "float intensity" [{num(intensity)}] '
                f'"color lightColor" [{nums(colour)}]{extra}',
                "  AttributeEnd",
            ]
        else:
            out.append(f'  LightSource "ambientlight" 2 "intensity" [{num(intensity)}] "lightcolor" [{nums(colour)}]')
    return "\n".join(out) + ("\n" if out else "")


# ---------------------------------------------------------------------------
# geometry
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


def part_material(part, handle: str, renderman22: bool) -> str:
    """The material lines of one archive part (see the module docstring, *Colour*)."""
    base = nums(part.colour)
    tinted = bool(getattr(part, "tinted", False))
    translucency = float(getattr(part, "translucency", 0.0) or 0.0)
    lines = []
    if renderman22:
        extra = ""
        if translucency > 0:
            extra = f' "float diffuseTransmitGain" [{num(translucency)}]'
        if tinted:
            lines += [
                f'    Pattern "PxrPrimvar" "{handle}_cs" "string varname" ["Cs"] "string type" ["color"]',
                f'    Pattern "PxrBlend" "{handle}_colour" "int operation" [18] '
                f'"reference color topRGB" ["{handle}_cs:resultRGB"] "float topA" [1] '
                f'"color bottomRGB" [{base}] "float bottomA" [1]',
                f'    Bxdf "PxrSurface" "{handle}" "reference color diffuseColor" ["{handle}_colour:resultRGB"]'
                + (f' "reference color diffuseTransmitColor" ["{handle}_colour:resultRGB"]' if translucency > 0 else "")
                + extra,
            ]
        else:
            lines += [f"    Color [{base}]", f'    Bxdf "PxrSurface" "{handle}" "color diffuseColor" [{base}]' + extra]
    else:
        if tinted:
            lines.append(f'    Surface "forest_tint" "color basecolour" [{base}]')
        else:
            lines += [f"    Color [{base}]", '    Surface "matte"']
    return "\n".join(lines) + "\n"


def archive_bytes(plan: SpeciesPlan, lod, meshes, bound, renderman22: bool) -> bytes:
    """One species level as a self-contained RIB archive (object space, metres, Y up)."""
    name = f"{plan.name}_{lod.name}"
    tris = sum(len(m.faces) for _, m in meshes)
    out = [
        HEADER,
        f"# forest tree archive: species {plan.model!r}, level {lod.name}, {tris} triangles\n".encode(),
        f"# object space: metres, Y up, base at the origin; bound [{fixed(bound6(bound))}]\n".encode(),
        b"AttributeBegin\n",
        f'  Attribute "identifier" "string name" [{rib_string(name)}]\n'.encode(),
        b'  Orientation "rh"\n',
    ]
    for k, (part, m) in enumerate(meshes):
        if len(m.faces) == 0:
            continue
        kind = getattr(part, "kind", "surface")
        handle = f"{name}_{kind}{k}"
        st = np.asarray(m.uv, dtype=np.float64).reshape(-1, 2)
        tint_note = ", tinted" if getattr(part, "tinted", False) else ""
        out += [
            f"  AttributeBegin  # part {k}: {kind}{tint_note}\n".encode(),
            f'    Attribute "identifier" "string name" [{rib_string(handle)}]\n'.encode(),
            b"    Sides 2\n" if kind == "leaf" else b"",
            part_material(part, handle, renderman22).encode(),
            points_polygons(m.vertices, m.faces, m.normals, st),
            b"  AttributeEnd\n",
        ]
    out.append(b"AttributeEnd\n")
    return b"".join(out)


def terrain_bytes(terrain, colour, renderman22: bool) -> bytes:
    material = (
        f'  Bxdf "PxrDiffuse" "terrain" "color diffuseColor" [{nums(colour)}]\n'
        if renderman22
        else '  Surface "matte"\n'
    )
    return b"".join(
        [
            HEADER,
            f"# forest terrain: {len(terrain.vertices)} vertices, {len(terrain.faces)} triangles, metres, Y up\n".encode(),
            b"AttributeBegin\n",
            b'  Attribute "identifier" "string name" ["terrain"]\n',
            b'  Orientation "rh"\n',
            f"  Color [{nums(colour)}]\n".encode(),
            material.encode(),
            points_polygons(terrain.vertices, terrain.faces, terrain.vertex_normals, terrain.uv, indent="  "),
            b"AttributeEnd\n",
        ]
    )


# ---------------------------------------------------------------------------
# level of detail
# ---------------------------------------------------------------------------


def detail_ranges(plan: SpeciesPlan, detail_bound: np.ndarray, config: Config, transition: float) -> list[list[float]]:
    """``DetailRange`` [minvisible lowertransition uppertransition maxvisible] per band.

    Area of the detail bound at distance d: A(d) = h·w·(f/d)² raster pixels²
    (module docstring).  Band [near, far) is fully visible for areas in
    [A(far·(1−τ)), A(near·(1+τ))], fades out towards A(far·(1+τ)) and in from
    A(near·(1−τ)); neighbouring bands cross-fade over the same interval.
    """
    size = detail_bound[1] - detail_bound[0]
    area = max(float(size[1]) * max(float(size[0]), float(size[2])), 1e-12)
    f = (config.render.width / 2) / math.tan(math.radians(config.camera.fov) / 2)

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


def check_transition(config: Config, transition: float) -> None:
    d = list(config.lod.bands)
    for a, b in itertools.pairwise(d):
        if b * (1 - transition) < a * (1 + transition):
            limit = (b - a) / (b + a)
            raise ConfigError(
                config.path,
                "export.lod_transition",
                f"{transition:g} makes the LOD bands around {a:g} m and {b:g} m overlap; use at most {limit:.3f}",
            )


# ---------------------------------------------------------------------------
# instance files
# ---------------------------------------------------------------------------


def tree_suffixes(
    plans: list[SpeciesPlan],
    archive_paths: dict,
    bounds: dict,
    config: Config,
    renderman22: bool,
    transition: float,
    lod_mode: str = "inline",
) -> tuple[dict, dict]:
    """Per species index, the constant text after a tree's ``Color`` (archive calls, LOD).

    Returns ``(suffixes, lod_archives)``: with ``lod_mode="archive"`` the
    ``Detail``/``DetailRange`` switch of a species with several levels goes to
    ``lod_archives[relative path] = bytes`` and each tree reads that archive
    with the union bound instead.
    """

    def procedural(path, bound, indent="  "):
        b = fixed(bound6(bound))
        if renderman22:
            return (
                f'{indent}Procedural2 "DelayedReadArchive2" "SimpleBound" "string filename" '
                f'[{rib_string(path)}] "float[6] bound" [{b}]'
            )
        return f'{indent}Procedural "DelayedReadArchive" [{rib_string(path)}] [{b}]'

    out, lod_archives = {}, {}
    for plan in plans:
        if len(plan.bands) == 1:
            lod = plan.bands[0].lod
            lines = [procedural(archive_paths[(plan.index, lod.name)], bounds[(plan.index, lod.name)])]
        else:
            bs = np.array([bounds[(plan.index, b.lod.name)] for b in plan.bands])
            detail = np.stack([bs[:, 0].min(axis=0), bs[:, 1].max(axis=0)])
            switch = [f"  Detail [{fixed(bound6(detail))}]"]
            for band, rng in zip(plan.bands, detail_ranges(plan, detail, config, transition)):
                switch.append(f"  DetailRange [{nums(rng, 6)}]")  # raster areas: 6 digits are plenty
                switch.append(
                    procedural(archive_paths[(plan.index, band.lod.name)], bounds[(plan.index, band.lod.name)])
                )
            if lod_mode == "archive":
                rel = f"archives/{plan.name}_lod.rib"
                text = [
                    HEADER.decode().rstrip("\n"),
                    f"# forest level-of-detail switch: species {plan.model!r}, levels "
                    + ", ".join(f"{b.lod.name} from {b.near:g} m" for b in plan.bands),
                    "# read by every tree: Detail and the bounds are in the tree's object space",
                    "AttributeBegin",
                    f'  Attribute "identifier" "string name" [{rib_string(plan.name + "_lod")}]',
                    *switch,
                    "AttributeEnd",
                    "",
                ]
                lod_archives[rel] = "\n".join(text).encode()
                lines = [procedural(rel, detail)]
            else:
                lines = switch
        lines.append("AttributeEnd\n")
        out[plan.index] = "\n".join(lines).encode()
    return out, lod_archives


def field_digits(instances: InstanceSet) -> dict:
    """Integer-part widths of the per-tree numbers, sized from the whole InstanceSet so the
    fixed-width text of a tree does not depend on how trees are split into blocks."""

    def digits(top):
        return len(str(int(math.ceil(float(top) * (1 + 1e-6) + 1e-6))))

    if len(instances) == 0:
        return {"matrix": 1, "position": 1, "colour": 1, "id": 1}
    return {
        "matrix": digits(np.abs(instances.scale).max()),
        "position": digits(np.abs(instances.position).max()),
        "colour": digits(np.abs(instances.tint).max()),
        "id": len(str(int(instances.id.max()))),
    }


def write_chunk(out: RowWriter, instances: InstanceSet, rows: np.ndarray, suffix: bytes, widths: dict) -> int:
    """Write the trees ``rows``: identifier, ConcatTransform (Mᵀ), Color, then ``suffix``.

    Numbers are fixed-width (:class:`forest.export.text.RowWriter`): RIB only
    needs whitespace between tokens, and the columns line up.
    """
    q = instances.rotation[rows].astype(np.float64)
    m = quaternion_to_matrix(q) * instances.scale[rows].astype(np.float64)[:, None, None]
    pos = instances.position[rows].astype(np.float64)
    md, pd, cd = widths["matrix"], widths["position"], widths["colour"]
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
            Field(pos, POSITION_DECIMALS, pad=True, int_digits=pd),
            b" 1]\n  Color [",
            Field(instances.tint[rows].astype(np.float64), COLOUR_DECIMALS, pad=True, int_digits=cd),
            b"]\n",
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
) -> int:
    """Stream one partition's trees to ``path``; returns the bytes written.

    Trees are grouped by species (in the order of the config's ``[[species]]``),
    in id order within a species, and formatted in blocks of :data:`CHUNK`, so
    memory stays bounded whatever the partition's size and the archive text
    after each tree's ``Color`` is one constant per block.
    """
    names = ", ".join(f"{p.name} ({p.model})" for p in plans)
    species = instances.species[rows]
    if len(rows) and not np.isin(species, list(suffixes)).all():
        raise ForestError("instances: a tree's species has no archive")
    rows = rows[np.argsort(species, kind="stable")]
    widths = field_digits(instances)
    bounds = np.searchsorted(np.sort(species), sorted(suffixes) + [np.iinfo(np.int64).max], side="left")
    written = 0
    with open(path, "wb") as fh:
        head = (
            HEADER.decode() + f"# forest instances: partition {partition!r}, {len(rows)} trees; species {names}\n"
            "# world: metres, Y up, right-handed. ConcatTransform is the tree's object-to-world\n"
            "# matrix M transposed (RenderMan transforms row vectors), Color its colour-map tint\n"
            "# (linear RGB); archive bounds are in the tree's object space.\n"
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
                    written += write_chunk(out, instances, r, suffixes[sp], widths)
                    done += len(r)
                    if progress:
                        progress(done / len(rows), partition)
        end = b"AttributeEnd\n"
        fh.write(end)
        written += len(end)
    return written


# ---------------------------------------------------------------------------
# scene files
# ---------------------------------------------------------------------------


def scene_text(
    config: Config, frame: int, instance_files: list[str], renderman22: bool, has_terrain: bool = True
) -> str:
    cam = config.camera
    r = config.render
    out = [
        HEADER.decode().rstrip("\n"),
        f"# forest scene {config.name!r}, frame {frame}",
        "# world: metres, Y up, right-handed; the camera transform maps it to RenderMan's",
        "# left-handed camera space (x right, y up, z forward), det = -1. Render from this folder.",
        f"FrameBegin {frame}",
    ]
    if not renderman22:
        out.append('  Option "searchpath" "string shader" ["shaders:&"]')
    out.append(f'  Display "{slug(config.name)}_{frame:04d}.exr" "openexr" "rgba"')
    out.append(f"  Format {r.width} {r.height} 1")
    if renderman22:
        out.append(f'  Hider "raytrace" "int minsamples" [{min(r.spp, 4)}] "int maxsamples" [{r.spp}]')
        out.append(f'  Integrator "PxrPathTracer" "integrator" "int maxPathLength" [{r.max_depth}]')
    else:
        ps = max(1, int(round(math.sqrt(r.spp))))
        out.append(f"  PixelSamples {ps} {ps}")
    state = camera_at(cam, frame)
    out.append(
        f'  Projection "perspective" "{"float " if renderman22 else ""}fov" '
        f"[{num(ri_fov(state.fov, r.width, r.height))}]"
    )
    out.append(f"  Clipping {num(cam.near)} {num(cam.far)}")
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
    out.append(lights_text(config, renderman22).rstrip("\n"))
    if has_terrain:
        out.append('  ReadArchive "terrain.rib"')
    for f in instance_files:
        out.append(f"  ReadArchive {rib_string(f)}")
    out.append("  WorldEnd")
    out.append("FrameEnd")
    return "\n".join(line for line in out if line) + "\n"


# ---------------------------------------------------------------------------
# the export
# ---------------------------------------------------------------------------


def export_rib(
    scene: Scene,
    out_dir: str | Path,
    *,
    renderman22: bool = False,
    frames: str | list[int] | None = None,
    progress=None,
) -> RibExport:
    """Write the RIB export of the scene's trees into ``out_dir`` (see the module docstring).

    ``frames``: a spec (``"1-120"``) or list; default the camera's keyed range, or
    frame 1.  Every file is written to a temporary folder first and moved into
    ``out_dir`` only when the whole export succeeded.
    """
    config, instances, terrain = scene.config, scene.instances, scene.terrain
    t0 = time.perf_counter()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ForestError(f"{out_dir}: exists and is not a folder")
    opts = export_options(config)
    check_transition(config, opts["lod_transition"])
    frame_list = export_frames(config, frames)
    check_instances(config, instances)
    plans = species_plans(scene)
    report = progress or (lambda f, m="": None)
    result = RibExport(out_dir=out_dir, trees=len(instances))
    try:
        with atomic_dir(out_dir) as tmp:
            if not renderman22:
                (tmp / "shaders").mkdir()
                (tmp / "shaders" / "forest_tint.sl").write_text(TINT_SHADER)
            # archives: one per species × level, written once
            archive_paths, bounds = {}, {}
            (tmp / "archives").mkdir()
            for plan in plans:
                for lod in plan.lods:
                    meshes = lod_mesh(lod)
                    bound = measured_bounds(lod, meshes)
                    rel = f"archives/{plan.name}_{slug(lod.name)}.rib"
                    data = archive_bytes(plan, lod, meshes, bound, renderman22)
                    (tmp / rel).write_bytes(data)
                    archive_paths[(plan.index, lod.name)] = rel
                    bounds[(plan.index, lod.name)] = bound
                    result.archives.append(out_dir / rel)
                    result.bytes += len(data)
            report(0.05, "archives")
            data = terrain_bytes(terrain, config.render.terrain_colour, renderman22)
            (tmp / "terrain.rib").write_bytes(data)
            result.terrain = out_dir / "terrain.rib"
            result.bytes += len(data)
            report(0.1, "terrain")
            # instance files: one per non-empty partition
            suffixes, lod_archives = tree_suffixes(
                plans, archive_paths, bounds, config, renderman22, opts["lod_transition"], opts["rib_lod"]
            )
            for rel, data in lod_archives.items():
                (tmp / rel).write_bytes(data)
                result.archives.append(out_dir / rel)
                result.bytes += len(data)
            parts = partition_rows(instances)
            total = max(1, len(instances))
            done = 0
            t1, c1 = time.perf_counter(), time.process_time()
            for _, pname, rows in parts:
                name = f"instances_{slug(pname)}.rib"

                def sub(f, m, d=done, n=len(rows)):
                    report(0.1 + 0.85 * (d + f * n) / total, f"partition {m}")

                result.bytes += write_instance_file(tmp / name, instances, rows, pname, suffixes, plans, sub)
                result.instance_files[pname] = out_dir / name
                done += len(rows)
            result.instance_seconds = time.perf_counter() - t1
            result.instance_cpu_seconds = time.process_time() - c1
            names = [p.name for p in result.instance_files.values()]
            for f in frame_list:
                rel = f"scene_{f:04d}.rib"
                text = scene_text(config, f, names, renderman22)
                (tmp / rel).write_text(text)
                result.scenes.append(out_dir / rel)
                result.bytes += len(text)
            report(1.0, "done")
    except OSError as e:  # disk full, permissions, a folder in the way: one line, nothing left
        raise ForestError(f"{out_dir}: cannot write the export: {e.strerror or e}") from None
    result.seconds = time.perf_counter() - t0
    return result
