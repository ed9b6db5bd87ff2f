"""A RIB checker for the tests: tokenizer, parser and a table of the RI calls the exporter uses.

The table follows the RenderMan Interface Specification 3.2 (its RIB binding,
appendix C, and the sections on options, attributes, transformations,
geometric primitives, motion and procedurals), plus the few RenderMan 22+
calls the ``--renderman22`` mode writes (``Light``, ``Bxdf``, ``Pattern``,
``Integrator``, ``Procedural2``).  For every call it knows the positional
arguments (count and kind), whether a parameter list follows, and the blocks
it may appear in:

* ``options`` — before ``WorldBegin`` (inside or outside ``FrameBegin``),
  never inside the world;
* ``world``   — only between ``WorldBegin`` and ``WorldEnd`` (archives are
  checked as if read inside the world);
* ``any``     — anywhere, e.g. transformations and attribute blocks;
* ``motion``  — transformations are the only calls allowed inside
  ``MotionBegin``/``MotionEnd``, one per time.

Parameter lists are checked too: every name is predeclared (spec 3.2, table
of standard variables) or declared inline (``"float[6] bound"``), and the
number of values matches its type — for ``PointsPolygons`` with vertex
primitive variables, the number of points the vertex indices reach.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

_TOKEN = re.compile(
    rb"""
    (?P<ws>[ \t\r\n]+)
  | (?P<comment>\#[^\n]*)
  | (?P<string>"(?:[^"\\\n]|\\.)*")
  | (?P<number>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)
  | (?P<open>\[)
  | (?P<close>\])
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
""",
    re.X,
)


class RibError(AssertionError):
    pass


@dataclass
class Call:
    name: str
    args: list = field(default_factory=list)
    line: int = 0


def tokenize(data: bytes):
    """Yield (kind, value, line): kinds ``string``, ``number``, ``open``, ``close``, ``name``."""
    pos, line, n = 0, 1, len(data)
    while pos < n:
        m = _TOKEN.match(data, pos)
        if not m:
            raise RibError(f"line {line}: cannot read {data[pos : pos + 20]!r}")
        kind = m.lastgroup
        text = m.group(kind)
        if kind == "string":
            yield "string", re.sub(rb"\\(.)", rb"\1", text[1:-1]).decode(), line
        elif kind == "number":
            yield "number", float(text), line
        elif kind in ("open", "close", "name"):
            yield kind, text.decode(), line
        line += text.count(b"\n")
        pos = m.end()


def parse(data: bytes) -> list[Call]:
    """Requests with their arguments; an array argument becomes a Python list."""
    calls: list[Call] = []
    array = None
    for kind, value, line in tokenize(data):
        if kind == "name":
            if array is not None:
                raise RibError(f"line {line}: request {value} inside an array")
            calls.append(Call(value, [], line))
        elif kind == "open":
            if array is not None:
                raise RibError(f"line {line}: nested array")
            array = []
        elif kind == "close":
            if array is None:
                raise RibError(f"line {line}: ']' without '['")
            if not calls:
                raise RibError(f"line {line}: array before any request")
            calls[-1].args.append(array)
            array = None
        else:
            if array is not None:
                if array and type(array[0]) is not type(value):
                    raise RibError(f"line {line}: array mixes strings and numbers")
                array.append(value)
            else:
                if not calls:
                    raise RibError(f"line {line}: value before any request")
                calls[-1].args.append(value)
    if array is not None:
        raise RibError("unterminated array at end of file")
    return calls


# ---------------------------------------------------------------------------
# the table
# ---------------------------------------------------------------------------
# Positional argument kinds: n number, s string, a array of numbers (aN: N of them),
# S string array of one, c3/c4: three/four numbers either bare or in one array,
# h a light handle (number in RI 3.2, string in later RIB).
#                    positional            params  context
TABLE = {
    "version": (["n"], False, "top"),
    "FrameBegin": (["n"], False, "top"),
    "FrameEnd": ([], False, "top"),
    "WorldBegin": ([], False, "options"),
    "WorldEnd": ([], False, "world"),
    "Option": (["s"], True, "options"),
    "Display": (["s", "s", "s"], True, "options"),
    "Format": (["n", "n", "n"], False, "options"),
    "PixelSamples": (["n", "n"], False, "options"),
    "Hider": (["s"], True, "options"),
    "Integrator": (["s", "s"], True, "options"),
    "Projection": (["s"], True, "options"),
    "Clipping": (["n", "n"], False, "options"),
    "Shutter": (["n", "n"], False, "options"),
    "Transform": (["a16"], False, "any"),
    "ConcatTransform": (["a16"], False, "any"),
    "Identity": ([], False, "any"),
    "MotionBegin": (["a"], False, "any"),
    "MotionEnd": ([], False, "any"),
    "TransformBegin": ([], False, "any"),
    "TransformEnd": ([], False, "any"),
    "AttributeBegin": ([], False, "any"),
    "AttributeEnd": ([], False, "any"),
    "Attribute": (["s"], True, "any"),
    "Orientation": (["s"], False, "any"),
    "Sides": (["n"], False, "any"),
    "Color": (["c3"], False, "any"),
    "Surface": (["s"], True, "any"),
    "Bxdf": (["s", "s"], True, "any"),
    "Pattern": (["s", "s"], True, "any"),
    "LightSource": (["s", "h"], True, "world"),
    "Light": (["s", "s"], True, "world"),
    "PointsPolygons": (["a", "a"], True, "world"),
    "Procedural": (["s", "S", "a6"], False, "world"),
    "Procedural2": (["s", "s"], True, "world"),
    "Detail": (["a6"], False, "any"),
    "DetailRange": (["c4"], False, "any"),
    "ReadArchive": (["s"], False, "world"),
    "ObjectBegin": (["h"], False, "any"),
    "ObjectEnd": ([], False, "any"),
    "ObjectInstance": (["h"], False, "world"),
}
#: RI 3.2 retained objects hold geometry only (section 5.6): the calls allowed between ObjectBegin and ObjectEnd.
OBJECT_CALLS = {"PointsPolygons", "Polygon", "GeneralPolygon", "PointsGeneralPolygons", "Sphere", "Patch", "NuPatch"}
TRANSFORMS = {"Transform", "ConcatTransform", "Identity"}
BLOCKS = {
    "ObjectBegin": "ObjectEnd",
    "FrameBegin": "FrameEnd",
    "WorldBegin": "WorldEnd",
    "AttributeBegin": "AttributeEnd",
    "TransformBegin": "TransformEnd",
    "MotionBegin": "MotionEnd",
}
ENDS = {v: k for k, v in BLOCKS.items()}

TYPE_SIZE = {
    "float": 1,
    "integer": 1,
    "int": 1,
    "string": 1,
    "color": 3,
    "point": 3,
    "vector": 3,
    "normal": 3,
    "hpoint": 4,
    "matrix": 16,
    "reference": 1,
}
# Predeclared variables (spec 3.2 standard variables and parameters) → (class, type, count)
PREDECLARED = {
    "P": ("vertex", "point", 1),
    "N": ("varying", "normal", 1),
    "Cs": ("varying", "color", 1),
    "Os": ("varying", "color", 1),
    "st": ("varying", "float", 2),
    "s": ("varying", "float", 1),
    "t": ("varying", "float", 1),
    "fov": ("uniform", "float", 1),
    "intensity": ("uniform", "float", 1),
    "lightcolor": ("uniform", "color", 1),
    "from": ("uniform", "point", 1),
    "to": ("uniform", "point", 1),
    "name": ("uniform", "string", 1),
    "Ka": ("uniform", "float", 1),
    "Kd": ("uniform", "float", 1),
}
# RenderMan 22+ adds a ``reference`` qualifier: the value names a pattern output ("node:out").
_DECL = re.compile(
    r"^(?:(constant|uniform|varying|vertex|facevarying)\s+)?(reference\s+)?"
    r"(float|integer|int|string|color|point|vector|normal|hpoint|matrix)"
    r"(?:\[(\d+)\])?\s+([A-Za-z_][A-Za-z0-9_:]*)$"
)


def declaration(token: str):
    """``(class, type, count, name)`` of a parameter token, inline or predeclared."""
    m = _DECL.match(token.strip())
    if m:
        cls, ref, typ, n, name = m.groups()
        return cls or "uniform", "reference" if ref else typ, int(n or 1), name
    if token in PREDECLARED:
        cls, typ, n = PREDECLARED[token]
        return cls, typ, n, token
    raise RibError(f"parameter {token!r} is neither predeclared nor declared inline")


def _numbers(v, n=None, what=""):
    if isinstance(v, list):
        if v and not isinstance(v[0], float):
            raise RibError(f"{what}: expected numbers")
        out = v
    elif isinstance(v, float):
        out = [v]
    else:
        raise RibError(f"{what}: expected numbers, got {v!r}")
    if n is not None and len(out) != n:
        raise RibError(f"{what}: expected {n} numbers, got {len(out)}")
    return out


def check_call(call: Call) -> dict:
    """Check one call against :data:`TABLE`; return its parameter list as {name: (decl, values)}."""
    if call.name not in TABLE:
        raise RibError(f"line {call.line}: unknown RI call {call.name}")
    spec, has_params, _ = TABLE[call.name]
    args = list(call.args)
    where = f"line {call.line}: {call.name}"
    for kind in spec:
        if kind in ("c3", "c4"):
            n = int(kind[1])
            if args and isinstance(args[0], list):
                _numbers(args.pop(0), n, where)
            else:
                if len(args) < n:
                    raise RibError(f"{where}: expected {n} numbers")
                _numbers([args.pop(0) for _ in range(n)], n, where)
            continue
        if not args:
            raise RibError(f"{where}: missing argument ({kind})")
        v = args.pop(0)
        if kind == "n" and not isinstance(v, float):
            raise RibError(f"{where}: expected a number, got {v!r}")
        if kind == "s" and not isinstance(v, str):
            raise RibError(f"{where}: expected a string, got {v!r}")
        if kind == "h" and not isinstance(v, (str, float)):
            raise RibError(f"{where}: expected a light handle, got {v!r}")
        if kind == "S" and not (isinstance(v, list) and len(v) == 1 and isinstance(v[0], str)):
            raise RibError(f"{where}: expected an array of one string, got {v!r}")
        if kind.startswith("a"):
            _numbers(v if isinstance(v, list) else None, int(kind[1:]) if len(kind) > 1 else None, where)
    params = {}
    if not has_params:
        if args:
            raise RibError(f"{where}: unexpected arguments {args[:3]!r}")
        return params
    if len(args) % 2:
        raise RibError(f"{where}: parameter list must be name/value pairs")
    for tok, val in zip(args[0::2], args[1::2]):
        if not isinstance(tok, str):
            raise RibError(f"{where}: parameter name must be a string, got {tok!r}")
        decl = declaration(tok)
        vals = val if isinstance(val, list) else [val]
        want_str = decl[1] in ("string", "reference")
        if vals and want_str != isinstance(vals[0], str):
            raise RibError(f"{where}: {tok!r} has values of the wrong kind")
        params[decl[3]] = (decl, vals)
        if decl[0] in ("uniform", "constant"):
            n = TYPE_SIZE[decl[1]] * decl[2]
            if len(vals) != n:
                raise RibError(f"{where}: {tok!r} needs {n} values, got {len(vals)}")
    if call.name == "PointsPolygons":
        nverts, verts = call.args[0], call.args[1]
        if any(v < 3 or v != int(v) for v in nverts):
            raise RibError(f"{where}: polygon vertex counts must be integers >= 3")
        if len(verts) != int(sum(nverts)):
            raise RibError(f"{where}: {len(verts)} vertex indices, the counts add up to {int(sum(nverts))}")
        if any(v < 0 or v != int(v) for v in verts):
            raise RibError(f"{where}: vertex indices must be non-negative integers")
        npts = int(max(verts)) + 1 if verts else 0
        if "P" not in params:
            raise RibError(f'{where}: no "P"')
        for name, (decl, vals) in params.items():
            cls, typ, n, _ = decl
            per = TYPE_SIZE[typ] * n
            if cls in ("vertex", "varying"):
                want = per * npts
            elif cls == "facevarying":
                want = per * len(verts)
            elif cls == "uniform":
                want = per * len(nverts)
            else:
                want = per
            if len(vals) != want:
                raise RibError(f"{where}: {name!r} has {len(vals)} values, expected {want}")
    return params


def check_calls(calls: list[Call], *, in_world: bool = False) -> None:
    """Check every call and the block structure; ``in_world`` for archives read inside the world."""
    stack: list[str] = []
    world = in_world
    motion: list | None = None
    for call in calls:
        check_call(call)
        name = call.name
        where = f"line {call.line}: {name}"
        if "ObjectBegin" in stack and name not in OBJECT_CALLS and name != "ObjectEnd":
            raise RibError(f"{where}: only geometric primitives may appear inside ObjectBegin/ObjectEnd")
        if name == "ObjectBegin" and "ObjectBegin" in stack:
            raise RibError(f"{where}: nested ObjectBegin")
        if motion is not None and name != "MotionEnd":
            if name not in TRANSFORMS:
                raise RibError(f"{where}: only transformations may appear inside MotionBegin/MotionEnd")
            motion[1] += 1
        ctx = TABLE[name][2]
        if ctx == "options" and world:
            raise RibError(f"{where}: an option is not allowed inside the world block")
        if ctx == "world" and not world:
            raise RibError(f"{where}: only allowed between WorldBegin and WorldEnd")
        if ctx == "top" and (world or any(b in ("AttributeBegin", "TransformBegin") for b in stack)):
            raise RibError(f"{where}: not allowed inside the world or an attribute block")
        if name == "Orientation" and call.args[0] not in ("outside", "inside", "lh", "rh"):
            raise RibError(f"{where}: bad orientation {call.args[0]!r}")
        if name == "Sides" and call.args[0] not in (1.0, 2.0):
            raise RibError(f"{where}: Sides must be 1 or 2")
        if name == "DetailRange":
            v = _numbers(call.args[0] if isinstance(call.args[0], list) else call.args, 4, where)
            if not (0 <= v[0] <= v[1] <= v[2] <= v[3]):
                raise RibError(f"{where}: values must be non-decreasing, got {v}")
        if name in ("Detail", "Procedural"):
            b = call.args[-1]
            if not (b[0] <= b[1] and b[2] <= b[3] and b[4] <= b[5]):
                raise RibError(f"{where}: bound must be [xmin xmax ymin ymax zmin zmax], got {b}")
        if name in BLOCKS:
            if name == "MotionBegin":
                if motion is not None:
                    raise RibError(f"{where}: nested motion block")
                times = call.args[0]
                if list(times) != sorted(times) or len(times) < 1:
                    raise RibError(f"{where}: times must be increasing")
                motion = [len(times), 0]
            if name == "WorldBegin":
                if world:
                    raise RibError(f"{where}: nested WorldBegin")
                world = True
            stack.append(name)
        elif name in ENDS:
            if not stack or stack[-1] != ENDS[name]:
                raise RibError(f"{where}: does not close {stack[-1] if stack else 'any block'}")
            stack.pop()
            if name == "WorldEnd":
                world = False
            if name == "MotionEnd":
                if motion[1] != motion[0]:
                    raise RibError(f"{where}: {motion[0]} times but {motion[1]} transformations")
                motion = None
    if stack:
        raise RibError(f"unclosed block {stack[-1]} at end of file")
    if world and not in_world:
        raise RibError("WorldBegin without WorldEnd")


def check_file(path: Path, *, in_world: bool = False) -> list[Call]:
    """Parse and check a RIB file; return its calls."""
    data = Path(path).read_bytes()
    if not data:
        raise RibError(f"{path}: empty file")
    try:
        calls = parse(data)
        check_calls(calls, in_world=in_world)
    except RibError as e:
        raise RibError(f"{path}: {e}") from None
    return calls


TEXTURE_SUFFIXES = (".tex", ".tx", ".tdl", ".txr")


def shader_parameters(source: Path) -> tuple[str, dict[str, str]]:
    """``(shader type, {parameter: type})`` of an RSL source's shader declaration."""
    text = re.sub(r"/\*.*?\*/|//[^\n]*", " ", Path(source).read_text(), flags=re.S)
    m = re.search(r"\b(surface|displacement|light|volume|imager)\s+([A-Za-z_]\w*)\s*\((.*?)\)\s*\{", text, re.S)
    if not m:
        raise RibError(f"{source}: no shader declaration")
    params = {}
    typ = None
    for decl in re.split(r"[;]", m.group(3)):
        for item in decl.split(","):
            item = item.strip()
            if not item:
                continue
            words = item.split("=")[0].split()
            if len(words) >= 2:
                typ = [w for w in words[:-1] if w not in ("uniform", "varying", "output")][-1]
            if typ is None:
                raise RibError(f"{source}: parameter {item!r} has no type")
            params[words[-1]] = typ
    return m.group(1), params


def references(call: Call) -> list[tuple[str, str]]:
    """Files a call refers to: ``("archive", path)``, ``("shader", name)`` or ``("texture", path)``."""
    out = []
    a = call.args
    if call.name == "ReadArchive":
        out.append(("archive", a[0]))
    elif call.name == "Procedural":
        out.append(("archive", a[1][0]))
    elif call.name == "Procedural2":
        out.append(("archive", a[a.index("string filename") + 1][0]))
    elif call.name == "Surface":
        out.append(("shader", a[0]))
    for tok, val in itertools.pairwise(a[1:]):
        if (isinstance(tok, str) and tok.split()[-1] in ("texturename", "lightColorMap")) or (
            call.name == "Pattern" and a[0] == "PxrTexture" and tok == "string filename"
        ):
            v = val[0] if isinstance(val, list) else val
            if v:
                out.append(("texture", v))
    return out


def texture_present(root: Path, ref: str) -> bool:
    """A texture exists, or it is a renderer's texture format made from the TIFF beside it."""
    p = Path(root) / ref
    if p.is_file():
        return True
    return p.suffix in TEXTURE_SUFFIXES and p.with_suffix(".tif").is_file()


def _matrix(call: Call) -> np.ndarray:
    return np.array(call.args[0], dtype=np.float64).reshape(4, 4)


class ExportChecker:
    """Cross-file checks of an export folder, following each scene file as a renderer reads it.

    * every referenced archive, shader source and texture exists;
    * every ``Surface`` parameter is a parameter of that shader's RSL source, with its type;
    * ``ObjectInstance`` names an object defined earlier in the world (scope);
    * every ``Procedural`` bound contains the geometry its archive draws — the
      extents of its ``PointsPolygons`` and of the objects it instances, through
      the archive's own transforms, and the bounds of the procedurals it calls —
      and every ``Detail`` bound contains the bounds of the levels it switches.
    """

    TOL = 1.01e-6

    def __init__(self, root: Path, calls: dict[str, list[Call]]):
        self.root = Path(root)
        self.calls = calls
        self.shaders: dict[str, dict[str, str]] = {}
        self.extents: dict[str, np.ndarray | None] = {}

    def shader(self, name: str) -> dict[str, str]:
        if name not in self.shaders:
            for folder in ("shaders", "."):
                src = self.root / folder / f"{name}.sl"
                if src.is_file():
                    self.shaders[name] = shader_parameters(src)[1]
                    break
            else:
                self.shaders[name] = {}
        return self.shaders[name]

    def check_references(self, rel: str, calls: list[Call]) -> None:
        for c in calls:
            for kind, ref in references(c):
                where = f"{rel}: line {c.line}: {c.name}"
                if kind == "archive" and not (self.root / ref).is_file():
                    raise RibError(f"{where} refers to missing {ref}")
                if kind == "texture" and not texture_present(self.root, ref):
                    raise RibError(f"{where} refers to missing texture {ref}")
                if kind == "shader" and ref not in ("matte", "plastic", "constant", "defaultsurface"):
                    declared = self.shader(ref)
                    if not declared:
                        raise RibError(f"{where}: no source for shader {ref!r}")
                    for name, (decl, _vals) in check_call(c).items():
                        if name not in declared:
                            raise RibError(f"{where}: shader {ref!r} has no parameter {name!r}")
                        if declared[name] != decl[1]:
                            raise RibError(f"{where}: {name!r} is a {declared[name]} in {ref!r}, given as {decl[1]}")

    def walk(self, rel: str, objects: dict, seen: set) -> np.ndarray | None:
        """Check one file in reading order; return the extents [min, max] of what it draws, in its own space."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        stack = [np.eye(4)]
        defining = None
        detail = None  # (bound, depth) of the last Detail

        def add(points: np.ndarray) -> None:
            nonlocal lo, hi
            if not len(points):
                return
            ph = np.c_[points, np.ones(len(points))] @ stack[-1]  # row vectors: p' = p·M
            lo, hi = np.minimum(lo, ph[:, :3].min(0)), np.maximum(hi, ph[:, :3].max(0))

        def corners(b) -> np.ndarray:
            return np.array([[x, y, z] for x in b[0:2] for y in b[2:4] for z in b[4:6]], dtype=np.float64)

        for c in self.calls[rel]:
            where = f"{rel}: line {c.line}: {c.name}"
            if c.name in ("AttributeBegin", "TransformBegin"):
                stack.append(stack[-1].copy())
            elif c.name in ("AttributeEnd", "TransformEnd"):
                stack.pop()
                if detail is not None and len(stack) < detail[1]:
                    detail = None
            elif c.name in ("ConcatTransform",) and defining is None:
                stack[-1] = _matrix(c) @ stack[-1]
            elif c.name in ("Transform", "Identity") and defining is None:
                stack[-1] = _matrix(c) if c.name == "Transform" else np.eye(4)
            elif c.name == "ObjectBegin":
                defining = (c.args[0], [])
            elif c.name == "ObjectEnd":
                pts = defining[1]
                objects[defining[0]] = (
                    np.stack([np.min([p.min(0) for p in pts], 0), np.max([p.max(0) for p in pts], 0)]) if pts else None
                )
                defining = None
            elif c.name == "PointsPolygons":
                params = check_call(c)
                P = np.array(params["P"][1], dtype=np.float64).reshape(-1, 3)
                if defining is not None:
                    defining[1].append(P)
                else:
                    add(P)
            elif c.name == "ObjectInstance":
                if c.args[0] not in objects:
                    raise RibError(f"{where}: object {c.args[0]!r} is not defined before it is instanced")
                ext = objects[c.args[0]]
                if ext is not None:
                    add(corners([ext[0, 0], ext[1, 0], ext[0, 1], ext[1, 1], ext[0, 2], ext[1, 2]]))
            elif c.name == "Detail":
                detail = (np.array(c.args[0], dtype=np.float64), len(stack))
            elif c.name in ("ReadArchive", "Procedural", "Procedural2"):
                ref = references(c)[0][1]
                if c.name == "ReadArchive":
                    if ref in seen:
                        raise RibError(f"{where}: {ref} read twice")
                    seen.add(ref)
                    ext = self.walk(ref, objects, seen)
                    if ext is not None:
                        add(ext)
                    continue
                a = c.args
                bound = np.array(a[2] if c.name == "Procedural" else a[a.index("float[6] bound") + 1], dtype=np.float64)
                if ref not in self.extents:
                    self.extents[ref] = self.walk(ref, objects, set())
                ext = self.extents[ref]
                if ext is not None:
                    b = bound.reshape(3, 2)
                    if np.any(ext[0] < b[:, 0] - self.TOL) or np.any(ext[1] > b[:, 1] + self.TOL):
                        raise RibError(f"{where}: bound {list(bound)} does not contain {ref}'s extents {ext.tolist()}")
                if detail is not None:
                    d = detail[0].reshape(3, 2)
                    b = bound.reshape(3, 2)
                    if np.any(b[:, 0] < d[:, 0] - self.TOL) or np.any(b[:, 1] > d[:, 1] + self.TOL):
                        raise RibError(f"{where}: bound {list(bound)} is not inside Detail {list(detail[0])}")
                add(corners(bound))
        if not np.isfinite(lo).all():
            return None
        return np.stack([lo, hi])


def check_export(root: Path) -> dict[str, list[Call]]:
    """Check every ``.rib`` under an export folder, then each scene as a renderer reads it.

    Per file: :func:`check_file` (calls, arity, parameter lists, block
    structure).  Across files (:class:`ExportChecker`): references, shader
    parameters, object scope, and procedural and detail bounds against the
    geometry they stand for.
    """
    out = {}
    root = Path(root)
    for p in sorted(root.rglob("*.rib")):
        rel = p.relative_to(root).as_posix()
        in_world = not rel.startswith("scene_")
        out[rel] = check_file(p, in_world=in_world)
    checker = ExportChecker(root, out)
    for rel, calls in out.items():
        checker.check_references(rel, calls)
    for rel in out:
        if rel.startswith("scene_"):
            checker.extents = {}
            checker.walk(rel, {}, set())
    return out


# ---------------------------------------------------------------------------
# reading trees back
# ---------------------------------------------------------------------------


def read_trees(calls: list[Call]) -> list[dict]:
    """The trees of an instance file: ``name``, ``matrix`` (4×4, column vectors),
    ``color``, ``archives`` [(file, bound)], ``detail``, ``ranges``."""
    trees = []
    cur = None
    depth = 0
    for c in calls:
        if c.name == "AttributeBegin":
            depth += 1
        elif c.name == "AttributeEnd":
            if cur is not None and depth == cur["depth"]:
                trees.append(cur)
                cur = None
            depth -= 1
        elif c.name == "Attribute" and c.args[0] == "identifier":
            val = c.args[2][0]
            if val.startswith("tree_"):
                cur = {"name": val, "depth": depth, "archives": [], "ranges": [], "detail": None}
        elif cur is None:
            continue
        elif c.name == "ConcatTransform":
            cur["matrix"] = np.array(c.args[0], dtype=np.float64).reshape(4, 4).T
        elif c.name == "Color":
            cur["color"] = np.array(c.args[0] if isinstance(c.args[0], list) else c.args[:3])
        elif c.name == "Detail":
            cur["detail"] = np.array(c.args[0])
        elif c.name == "DetailRange":
            cur["ranges"].append(np.array(c.args[0]))
        elif c.name == "Procedural":
            cur["archives"].append((c.args[1][0], np.array(c.args[2])))
        elif c.name == "Procedural2":
            a = c.args
            cur["archives"].append((a[a.index("string filename") + 1][0], np.array(a[a.index("float[6] bound") + 1])))
    return trees


def points_polygons(calls: list[Call]) -> list[dict]:
    """Meshes of an archive: ``faces`` (F, 3), ``P``, ``N``, ``st`` as arrays."""
    out = []
    for c in calls:
        if c.name != "PointsPolygons":
            continue
        params = check_call(c)
        m = {"faces": np.array(c.args[1], dtype=np.int64).reshape(-1, 3)}
        for k, (decl, vals) in params.items():
            m[k] = np.array(vals, dtype=np.float64).reshape(-1, TYPE_SIZE[decl[1]] * decl[2])
        out.append(m)
    return out


def objects(calls: list[Call]) -> dict:
    """Retained objects of a file: {handle: mesh} with the mesh as in :func:`points_polygons`."""
    out = {}
    handle = None
    body: list[Call] = []
    for c in calls:
        if c.name == "ObjectBegin":
            handle, body = c.args[0], []
        elif c.name == "ObjectEnd":
            (out[handle],) = points_polygons(body)
            handle = None
        elif handle is not None:
            body.append(c)
    return out
