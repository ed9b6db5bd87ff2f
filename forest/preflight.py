"""Pre-flight: what a command can check before it starts work, and what it will cost.

Every long command runs these checks first, so that a mistake costs a second,
not a render: each raises :class:`~forest.errors.ForestError` (a
:class:`~forest.errors.ParameterError` naming the parameter, or a
:class:`~forest.errors.ConfigError` naming the file and field) with one line.
Nothing here writes anything the user would see: writability is probed with a
temporary file that is removed at once.

* **Output paths** (:func:`output_file`, :func:`output_folder`): the nearest
  existing ancestor must be a folder this process can create files in (the
  missing folders below it are created when the output is written), a file
  must not be asked for where a folder stands and vice versa, and every name
  must fit the file system's name limit.
* **Species** (:func:`check_species`): every ``[[species]]`` and
  ``[[ground_cover]]`` model names a library species, ``NAME@SEED`` of one, or
  an existing mesh file — checked
  before scatter, so a misspelling fails at ``forest scatter`` and not at the
  end of a render (with the closest names as a suggestion).  A scene draws on
  at most :data:`MAX_TREE_VARIANTS` generated variants (individuals and seeds);
  of those, the ones not yet in the library's cache are generated on first use
  (about 2 s and 6 MB each): over :data:`WARN_NEW_VARIANTS` a warning says how
  many, how long and how much disk, and over :data:`MAX_NEW_VARIANTS`
  (``$FOREST_ALLOW_GENERATE`` sets another number) the run is refused before
  any work (:func:`variants_to_generate`, :func:`check_generation`).
* **Memory** (:func:`render_estimate`, :func:`check_render_memory`): a render
  needs, to first order,

      M ≈ M₀ + m_tri · T_unique + m_tree · N + m_px · W·H + m_lane · L

  where N is the number of trees (each an instance record and its share of the
  acceleration structure), T_unique the triangles of the levels of detail of
  every species' individuals (:func:`unique_triangles`), W·H the image (the
  film, the running and accumulated beauty in float64, the depth/id/species
  layers and the copies made to write the EXR and PNG) and L the rays one sample pass traces at once in the JIT variants
  (:data:`JIT_LANES` at most).  In the JIT variants
  (forest_path) the trees at the far level are not instances: they are merged
  into one world-space mesh per species and part
  (:mod:`forest.render.path.geometry`), so there

      m_tree · N  →  m_inst · N_inst + m_flat · T_far + m_row · N

  with N_inst the trees that stay instances, T_far the merged triangles —
  with the skirt to the horizon's, world-space too (:func:`world_triangles`:
  0.1–1.5 M with hills and woods, cut finer for a narrower view) — and
  m_row each tree's own arrays (transform, normal matrix, ids).  The
  coefficients are measured peak resident sizes of ``forest render`` in
  Mitsuba 3.9.1, rounded up: M₀ ≈ 0.27 GB (a few trees, a small image);
  scalar_rgb ≈ 920 B per pixel on the demo (400×225 → 1200×675: 1.93 →
  2.55 GiB) and 950–1 580 B on a small forest (256² → 768²), counted as
  1 400, and ≈ 510 B per loaded triangle (the demo's 3.2 M, its prototypes
  times their colour-jitter bins, :func:`unique_triangles`: 1.85 GiB at no
  pixels; the 183 B per pixel and 200 B per triangle measured before
  Cryptomatte, the AOVs and the bins had the demo at 0.43× its peak);
  forest_path ≈ 770 B per
  pixel (its beauty, alpha, albedo, normal and per-sample id accumulators:
  130 000 trees at 480×270 and 960×540, 64 spp, 1.48 → 1.76 GiB) and ≈ 72 B
  per lane (one queued pass's outputs, :data:`BYTES_PER_LANE`); per tree ≈ 4.6 KB in scalar_rgb between 100 000 and
  1 000 000 instances (bench/RESULTS.md, "render million": 4.83 GB); in
  llvm_ad_rgb 14.0–15.8 KB per instance (``bench/bench_render.py --case
  jit_memory``; :data:`BYTES_PER_INSTANCE` rounds it up to the 16 KB
  forest_path's own check uses), 128 B per merged triangle, ≈ 1 KB per tree
  and ≈ 800 B per unique triangle, fitted to two measured peaks: 130 000
  trees (46 647 instances, 480×270, 64 spp) 1.48 GiB measured, 1.45
  estimated; 1 000 000 trees (56 481 instances, 9.58 M merged triangles)
  2.73 GiB measured, 3.43 estimated.
  ``bench/bench_preflight.py`` compares estimate and measurement.
  The estimate is compared with the memory this process may use
  (:func:`available_memory`: :func:`forest.memory.memory_room`, the least of
  ``MemAvailable`` and the room under every limit of the process's own cgroup
  and its parents, v1 or v2, or ``$FOREST_MEMORY_GB``; a cgroup limit that binds
  is named in the messages); a render that does not fit fails before rendering
  naming ``render.width``/``render.height`` and the largest image of the same
  aspect ratio that fits or, when the trees alone do not fit, ``scatter.count``
  and about how many trees would.
* **Time**: samples × seconds-per-sample + trees × seconds-per-tree, with the
  rates measured by this machine's last render of the same variant
  (:func:`record_render`, kept in the user state folder) or, before any, rates
  measured on a 2-core machine and scaled by the core count.  Shown as
  "about …"; it is a forecast, not a promise.
"""

from __future__ import annotations

import difflib
import errno
import json
import math
import os
import re
import stat
import tempfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from . import memory
from .errors import ConfigError, ForestError, ParameterError
from .memory import Room

if TYPE_CHECKING:
    from .render.frame import FrameSize
    from .scene import Scene

GiB = 1 << 30

# -- memory model (bytes), see the module docstring --------------------------------------------
BASE_BYTES = 300 << 20
#: scalar_rgb: bytes per loaded triangle (its shapegroups' meshes and BVHs).
BYTES_PER_TRIANGLE = 520
#: JIT variants: bytes per unique triangle (forest_path's part buffers and Mitsuba's shapegroup meshes).
BYTES_PER_TRIANGLE_JIT = 800
BYTES_PER_TREE = {"scalar": 4_700, "jit": 18_000}
#: JIT variants (forest_path): bytes per tree that stays an instance, per merged far-level triangle,
#: and per tree whatever its level (its rows in forest's own buffers).
BYTES_PER_INSTANCE = 16 * 1024
BYTES_PER_FLAT_TRIANGLE = 128
BYTES_PER_ROW = 1000
BYTES_PER_PIXEL = {"scalar": 1400, "jit": 800}
#: Bytes per lane of a pass: one pass's per-sample outputs (radiance, coverage, first-hit row, segments, albedo,
#: normal: 48 B) and its per-pixel sums (36 B at one sample per pixel) stay alive while the next pass runs
#: (``PathScene.passes`` queues pass k before pass k − 1 is added): the case study at 1920×1080 peaked
#: 0.14 GiB higher (2.81 → 2.95 GiB) once passes were queued, ≈ 70 B per lane of its 2²¹-lane passes.
BYTES_PER_LANE = 72
#: Rays one JIT sample pass traces at most: forest_path's ``forest.render.path.frame.MAX_LANES`` (kept equal by
#: tests/test_structure.py; not imported, so the pre-flight check loads no renderer).
JIT_LANES = 1 << 21

# -- time model (seconds), used until this machine has rendered once ---------------------------
#: Seconds per camera sample and per tree loaded on a 2-core machine (samples scale with the cores).
SECONDS_PER_SAMPLE = {"scalar": 8e-6, "jit": 2e-6}
SECONDS_PER_TREE = {"scalar": 2.2e-5, "jit": 1.0e-4}
#: Fixed cost of building the scene (and, in the JIT variants, compiling the kernels).
SECONDS_FIXED = {"scalar": 2.0, "jit": 15.0}

#: Environment variable that states the memory (GiB) a render may use, instead of measuring it.
MEMORY_ENV = "FOREST_MEMORY_GB"


def _kind(variant: str) -> str:
    return "scalar" if variant.startswith("scalar") else "jit"


# ---------------------------------------------------------------------------------------------
# Output paths
# ---------------------------------------------------------------------------------------------


def _name_max(folder: Path) -> int:
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        return 255


def _shown(path: Path) -> str:
    """``path`` for a message, with any name over 40 characters shortened."""
    parts = [p if len(p) <= 40 else f"{p[:16]}…{p[-8:]}" for p in path.parts]
    return str(Path(*parts)) if parts else str(path)


def _is_dir(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:  # a name the file system cannot even look up (too long, …)
        return False


def _existing_ancestor(path: Path, field: str) -> Path:
    """The nearest existing ancestor of ``path`` (which must be a folder), checking the names to create."""
    limit = _name_max(Path("/"))
    for name in path.parts:
        if len(os.fsencode(name)) > limit:
            raise ParameterError(field, f"{_shown(path)}: the name {_shown(Path(name))} is longer than {limit} bytes")
    folder = path.parent
    while not os.path.lexists(folder):
        if folder.parent == folder:
            break
        folder = folder.parent
    if not _is_dir(folder):
        raise ParameterError(field, f"{path}: {folder} is a file, not a folder")
    return folder


def _probe(folder: Path, path: Path, field: str) -> None:
    """Create and remove a temporary file in ``folder``; a one-line error naming ``path`` if that fails."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".forest-probe.", dir=folder)
    except OSError as e:
        reason = e.strerror or str(e)
        if e.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
            reason = "permission denied" if e.errno != errno.EROFS else "read-only file system"
        raise ParameterError(field, f"{path}: cannot write into {folder}: {reason}") from None
    os.close(fd)
    os.unlink(tmp)


def special_file(path: str | Path) -> str | None:
    """What ``path`` is when it exists and is neither a regular file nor a folder ("a device", "a named pipe",
    "a socket"), else None.  An output there is refused: the atomic writer would replace the node itself
    (``-o /dev/null`` run as root turned the device into a file)."""
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a named pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return None


def _not_special(path: Path, field: str) -> None:
    kind = special_file(path)
    if kind is not None:
        raise ParameterError(field, f"{path}: is {kind}, not a file; give a file name")


def output_file(path: str | Path, *, field: str = "output") -> Path:
    """Check that a file can be written at ``path`` (folders above it may still be missing).

    Refused: a folder at ``path``; a device, named pipe or socket at ``path``;
    a file where one of its folders should be; a folder this process cannot
    create files in; a name too long for the file system.  Nothing is created.
    """
    path = Path(path)
    folder = _existing_ancestor(path, field)
    if _is_dir(path):
        raise ParameterError(field, f"{path}: is a folder; give a file name")
    _not_special(path, field)
    _probe(folder, path, field)
    return path


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def distinct_from_inputs(
    outputs: Iterable[str | Path], inputs: Iterable[str | Path | None], *, field: str = "output"
) -> None:
    """Refuse an output that is one of the command's inputs (the same file, through any link or path).

    Writing it would replace what the command reads — ``forest match scene.toml … -o .`` replaced the
    user's scene with the fitted one.  ``outputs`` are the files the command will write (those of an
    output folder included); ``inputs`` the files it reads (None entries are skipped).
    """
    ins = [Path(p) for p in inputs if p is not None]
    for out in outputs:
        out = Path(out)
        for inp in ins:
            if _same_file(out, inp):
                shown = "" if out == inp else f" (as {inp})"
                raise ParameterError(
                    field, f"{out}: is an input of this command{shown}; writing it would replace it — give another name"
                )


def output_files(paths: Iterable[str | Path], *, field: str = "output") -> list[Path]:
    """:func:`output_file` for several files (a frame sequence), probing each distinct folder once."""
    out: list[Path] = []
    probed: set[Path] = set()
    for p in paths:
        p = Path(p)
        folder = _existing_ancestor(p, field)
        if _is_dir(p):
            raise ParameterError(field, f"{p}: is a folder; give a file name")
        _not_special(p, field)
        if folder not in probed:
            _probe(folder, p, field)
            probed.add(folder)
        out.append(p)
    return out


#: Bytes per pixel of one written frame: the float EXR's beauty, depth, id and species layers after
#: zip compression (noisy beauty compresses little, the id layers much) plus the 8-bit PNG.
FRAME_BYTES_PER_PIXEL = 16


def check_free_space(path: str | Path, needed: int, *, field: str = "output") -> None:
    """Refuse ``needed`` bytes of output at ``path`` when its file system has less room left."""
    import shutil

    folder = _existing_ancestor(Path(path), field)
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if needed > free:
        raise ParameterError(
            field, f"{path}: the output needs about {format_bytes(needed)}, {format_bytes(free)} free on its disk"
        )


def output_folder(path: str | Path, *, field: str = "output") -> Path:
    """Check that folder ``path`` can be created or written into (files are written inside it)."""
    path = Path(path)
    folder = _existing_ancestor(path, field)
    if os.path.lexists(path) and not _is_dir(path):
        raise ParameterError(field, f"{path}: exists and is not a folder")
    _probe(folder, path, field)
    if _is_dir(path):
        _probe(path, path, field)
    return path


def output_folder_argument(path: str | Path) -> Path:
    """:func:`output_folder` for a positional argument: the message names the folder alone."""
    try:
        return output_folder(path)
    except ParameterError as e:
        raise ForestError(e.message) from None


def input_file(path: str | Path, *, field: str | None, what: str = "file") -> Path:
    """Check that ``path`` is an existing, readable, non-empty file.

    A one-line error naming ``field`` (an option's parameter), or only the file
    when ``field`` is None (a positional argument: the file is what the user typed).
    """
    path = Path(path)

    def error(message: str) -> ForestError:
        return ForestError(message) if field is None else ParameterError(field, message)

    if _is_dir(path):
        raise error(f"{path}: is a folder, not a {what}")
    if not path.is_file():
        raise error(f"{path}: {what} not found")
    try:
        with open(path, "rb") as f:
            first = f.read(1)
    except OSError as e:
        raise error(f"{path}: cannot read {what}: {e.strerror or e}") from None
    if not first:
        raise error(f"{path}: {what} is empty")
    return path


# ---------------------------------------------------------------------------------------------
# Species
# ---------------------------------------------------------------------------------------------


#: Library tree variants (a species' individuals, each ``NAME@SEED`` its own) one scene may draw on.  Each is
#: generated on first use; 10 000 seeded species once ran for hours and filled the user library.  256 is 64
#: species of 4 individuals, or one of 255.
MAX_TREE_VARIANTS = 256
#: What generating one variant costs, for the message (a broadleaf on the 2-core reference machine).
VARIANT_SECONDS, VARIANT_MB = 2.0, 6.0


def check_species(config, library) -> None:
    """Every ``[[species]]`` and ``[[ground_cover]]`` model names a library species, ``NAME@SEED`` of one, or a mesh.

    Resolving (building a species, importing a mesh) is left to the scene;
    this only catches what would fail there.  A misspelled name gets the
    closest library names as suggestions.  The job service runs it at submission.
    """
    names = library.names()
    known = set(names)
    cover = getattr(getattr(config, "model", None), "ground_cover", None) or []
    models = [(f"species[{i}].model", sp) for i, sp in enumerate(config.species)]
    models += [(f"ground_cover[{j}].model", gc) for j, gc in enumerate(cover)]
    from .config.schema import individual_count

    variants = 0
    for field, sp in models:
        model = sp.model
        if not sp.is_mesh:
            variants += individual_count(model, getattr(sp, "individuals", None))
            if variants > MAX_TREE_VARIANTS:
                raise ConfigError(
                    config.path,
                    field,
                    f"the species up to here draw {variants:,} tree variants (individuals and seeds, each built on "
                    f"first use: about {VARIANT_SECONDS:g} s and {VARIANT_MB:g} MB); at most {MAX_TREE_VARIANTS} a "
                    "scene — use fewer species, seeds or individuals",
                )
        if sp.is_mesh:
            p = Path(model).expanduser()
            p = p if p.is_absolute() else config.base_dir / p
            if not p.is_file():
                raise ConfigError(config.path, field, f"mesh file not found: {model}")
            continue
        base = m.group(1) if (m := re.fullmatch(r"(.+)@(\d+)", model)) else model
        if base in known:
            continue
        close = difflib.get_close_matches(base, names, n=3, cutoff=0.6)
        hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
        raise ConfigError(
            config.path,
            field,
            f"unknown species {model!r}{hint} (the library has {', '.join(names) or 'no species'}; "
            "or name a mesh file)",
        )
    check_generation(config, library)


#: Generated tree variants one run may build (those not yet in the library's cache) before it is refused;
#: ``$FOREST_ALLOW_GENERATE`` (:data:`GENERATE_ENV`) sets another number.  64 is about 2 minutes and 400 MB.
MAX_NEW_VARIANTS = 64
#: Over this many variants to generate, a warning says how many, how long and how much disk.
WARN_NEW_VARIANTS = 8
#: Environment variable: how many tree variants one run may generate (a whole number; 0 refuses any).
GENERATE_ENV = "FOREST_ALLOW_GENERATE"


def allowed_new_variants() -> int:
    """How many tree variants one run may generate: ``$FOREST_ALLOW_GENERATE``, else :data:`MAX_NEW_VARIANTS`."""
    env = os.environ.get(GENERATE_ENV)
    if env is None or not env.strip():
        return MAX_NEW_VARIANTS
    text = env.strip()
    if not text.isdigit():
        raise ForestError(f"${GENERATE_ENV}: must be a whole number of tree variants >= 0, got {env!r}")
    return int(text)


def _real_library(library):
    """The :class:`~forest.library.Library` behind ``library`` (itself, or its ``library``), None if there is none."""
    lib = getattr(library, "library", library)
    return lib if all(hasattr(lib, a) for a in ("get", "entry", "recipe")) else None


def variants_to_generate(config, library) -> list[tuple[str, str]]:
    """``(field, label)`` of every generated tree variant the scene draws on that the library has not built yet.

    A generated species ``NAME`` (manifest seed b) or ``NAME@b`` with c individuals draws seeds b … b + c − 1
    (:mod:`forest.library.individuals`); each distinct variant is counted once, by the first field naming it.
    Empty for a library object that cannot tell (one that only knows the names).
    """
    lib = _real_library(library)
    if lib is None:
        return []
    from .config.schema import individual_count

    cover = getattr(getattr(config, "model", None), "ground_cover", None) or []
    models = [(f"species[{i}].model", sp) for i, sp in enumerate(config.species)]
    models += [(f"ground_cover[{j}].model", gc) for j, gc in enumerate(cover)]
    seen: set[tuple[str, int]] = set()
    out: list[tuple[str, str]] = []
    for field, sp in models:
        if sp.is_mesh:
            continue
        m = re.fullmatch(r"(.+)@(\d+)", sp.model)
        name = m.group(1) if m else sp.model
        try:
            if lib.entry(name).get("source", "generated") != "generated":
                continue
            base = int(m.group(2)) if m else lib.recipe(name)[1]
        except ForestError:
            continue  # a broken library entry: the scene names it as it loads
        count = individual_count(sp.model, getattr(sp, "individuals", None))
        for seed in range(base, base + max(1, count)):
            if (name, seed) in seen:
                continue
            seen.add((name, seed))
            try:
                lib.get(name, seed=seed, build=False)
            except ForestError:
                out.append((field, f"{name}@{seed}"))
    return out


def _generation_cost(n: int) -> str:
    return f"about {format_seconds(n * VARIANT_SECONDS)} and {n * VARIANT_MB:,.0f} MB"


def check_generation(config, library) -> int:
    """Refuse a scene that would generate more tree variants than one run may; warn over a few; return how many.

    The limit is :func:`allowed_new_variants`; the error names the field at which the count passes it, the
    count and its cost.  Over :data:`WARN_NEW_VARIANTS` (and within the limit) a
    :class:`~forest.errors.ForestWarning` says how many will be generated first, how long and how much disk.
    """
    import warnings

    from .errors import ForestWarning

    allowed = allowed_new_variants()
    new = variants_to_generate(config, library)
    if len(new) > allowed:
        field = new[allowed][0]
        raise ConfigError(
            config.path,
            field,
            f"the scene needs {len(new):,} tree variants the library has not built yet ({_generation_cost(len(new))}"
            f" to generate); at most {allowed} a run — set ${GENERATE_ENV}={len(new)} to build them, or use fewer "
            "seeds or individuals",
        )
    if len(new) > WARN_NEW_VARIANTS:
        warnings.warn(
            f"{config.path}: {len(new)} tree variants are not built yet and are generated first "
            f"({_generation_cost(len(new))} in the tree library; machines of a render farm share one: "
            "$FOREST_LIBRARY)",
            ForestWarning,
            stacklevel=3,
        )
    return len(new)


# ---------------------------------------------------------------------------------------------
# Memory and time
# ---------------------------------------------------------------------------------------------


def memory_room() -> Room | None:
    """The memory this process may still use: ``$FOREST_MEMORY_GB``, else :func:`forest.memory.memory_room`
    (the least of the machine's available memory and the room under each of its cgroups' limits, with the
    cgroup that binds); None where neither can be read."""
    env = os.environ.get(MEMORY_ENV)
    if env:
        try:
            gb = float(env)
        except ValueError:
            gb = float("nan")
        if not (math.isfinite(gb) and gb > 0):
            raise ForestError(f"${MEMORY_ENV}: must be a positive number of GiB, got {env!r}")
        return Room(int(gb * GiB))
    return memory.memory_room()


def available_memory() -> int | None:
    """:func:`memory_room` in bytes alone."""
    room = memory_room()
    return None if room is None else room.bytes


def _available(room: int | Room) -> str:
    """``1.0 GiB available``, naming the cgroup limit when one binds: ``… (cgroup limit of 1.0 GiB on /a/b)``."""
    if isinstance(room, int):
        return f"{format_bytes(room)} available"
    text = f"{format_bytes(room.bytes)} available"
    if room.cgroup is not None:
        text += f" (cgroup limit of {format_bytes(room.cgroup.limit)} on {room.cgroup.path})"
    return text


@dataclass(frozen=True)
class RenderEstimate:
    """What a render will need: peak memory in bytes and wall-clock seconds (both approximate)."""

    width: int
    height: int
    spp: int
    frames: int
    trees: int
    variant: str
    triangles: int
    memory: int
    seconds: float
    measured: bool  # the time comes from this machine's last render (else from the built-in rates)
    far_trees: int | None = None  # JIT variants: trees merged at the far level (None: not known yet)
    far_triangles: int = 0

    def line(self, available: int | Room | None = None) -> str:
        """One line for the user: size, samples, trees, memory and time (``available``: bytes, or a
        :class:`~forest.memory.Room` whose binding cgroup limit is named)."""
        frames = f"{self.frames} frames" if self.frames > 1 else "1 frame"
        room = f" of {_available(available)}" if available is not None else ""
        return (
            f"{frames} {self.width}x{self.height} at {self.spp} spp, {self.trees:,} trees: "
            f"about {format_bytes(self.memory)}{room}, about {format_seconds(self.seconds)}"
        )


def tree_bytes(trees: int, variant: str, *, far_trees: int | None = None, far_triangles: int = 0) -> int:
    """Bytes the trees themselves take in ``variant`` (see the module docstring).

    ``far_trees`` (JIT variants): how many of the ``trees`` are merged at the far level, with
    ``far_triangles`` triangles in all; None when unknown (before the scene is loaded): every tree
    is then counted as an instance, the bound of :data:`BYTES_PER_TREE`."""
    trees = int(trees)
    if _kind(variant) == "scalar":
        return BYTES_PER_TREE["scalar"] * trees
    if far_trees is None:
        return BYTES_PER_TREE["jit"] * trees
    far = min(max(int(far_trees), 0), trees)
    return BYTES_PER_INSTANCE * (trees - far) + BYTES_PER_FLAT_TRIANGLE * int(far_triangles) + BYTES_PER_ROW * trees


def render_memory(
    width: int,
    height: int,
    spp: int,
    trees: int,
    variant: str,
    triangles: int = 0,
    *,
    far_trees: int | None = None,
    far_triangles: int = 0,
) -> int:
    """Peak bytes of a render (the model in the module docstring; ``far_*`` as in :func:`tree_bytes`)."""
    kind = _kind(variant)
    pixels = int(width) * int(height)
    mem = BASE_BYTES + (BYTES_PER_TRIANGLE if kind == "scalar" else BYTES_PER_TRIANGLE_JIT) * int(triangles)
    mem += tree_bytes(trees, variant, far_trees=far_trees, far_triangles=far_triangles)
    mem += BYTES_PER_PIXEL[kind] * pixels
    if kind == "jit":
        mem += BYTES_PER_LANE * min(JIT_LANES, pixels * max(1, int(spp)))
    return int(mem)


def render_estimate(
    width: int,
    height: int,
    spp: int,
    trees: int,
    variant: str,
    *,
    frames: int = 1,
    subframes: int = 1,
    triangles: int = 0,
    far_trees: int | None = None,
    far_triangles: int = 0,
) -> RenderEstimate:
    """Memory and time of rendering ``frames`` frames (time from :func:`throughput`; ``far_*`` as in
    :func:`tree_bytes`)."""
    kind = _kind(variant)
    sample_s, tree_s, measured = throughput(variant)
    samples = int(width) * int(height) * max(int(spp), int(subframes))
    seconds = SECONDS_FIXED[kind] + frames * (samples * sample_s + trees * tree_s * max(1, subframes))
    return RenderEstimate(
        width=int(width),
        height=int(height),
        spp=int(spp),
        frames=int(frames),
        trees=int(trees),
        variant=variant,
        triangles=int(triangles),
        memory=render_memory(
            width, height, spp, trees, variant, triangles, far_trees=far_trees, far_triangles=far_triangles
        ),
        seconds=seconds,
        measured=measured,
        far_trees=far_trees,
        far_triangles=int(far_triangles),
    )


def unique_triangles(scene: Scene, variant: str = "llvm_ad_rgb") -> int:
    """The triangles of every level of every individual of every species — what both renderers build once and
    instance (:func:`forest.render.path.from_scene.scene_species`; counting one individual a species left the
    gallery's peaks 15–35 % above the estimate).  ``scalar_rgb`` loads a prototype of T triangles once per
    colour-jitter bin when the trees are jittered, k = :func:`forest.render.instancing.jitter_bin_count` (T)
    copies (on the demo 0.9 → 3.1 M loaded triangles)."""
    from .render.path.from_scene import scene_species

    lists, _ = scene_species(scene)
    counts = [lod.triangles for group in lists for sp in group for lod in sp.lods]
    if _kind(variant) == "scalar" and scene.tree_jitter() is not None:
        from .render.instancing import jitter_bin_count

        return sum(t * jitter_bin_count(t) for t in counts)
    return sum(counts)


def world_triangles(scene: Scene, frames: Sequence[float], width: int) -> int:
    """forest_path's world-space triangles beyond the trees that the model counts as merged ones: the skirt to
    the horizon (:func:`forest.skirt.skirt_triangles`; with hills and woods its rings are cut finer for a
    narrower field of view or a wider image, :func:`forest.skirt.relief_step` — the narrowest of ``frames``)."""
    from .skirt import hills, relief_step, skirt_triangles

    rc = scene.config.render
    if not rc.horizon_ground:
        return 0
    h = hills(scene.config)
    relief = (
        h is not None and rc.horizon_hills is not None and bool(rc.horizon_hills.woods) and len(scene.instances) > 0
    )
    fov = min(float(scene.camera_at(float(f)).fov) for f in (frames or [1.0]))
    return skirt_triangles(scene.terrain, h, relief, relief_step(fov, int(width)))


def scene_render_estimate(scene: Scene, variant: str, frames: Sequence[float], size: FrameSize) -> RenderEstimate:
    """:func:`render_estimate` of a loaded Scene: its trees and their triangles at ``size``, and in the JIT
    variants the trees merged at the far level for ``frames`` (:func:`forest.render.path.from_scene.far_plan`).

    The one post-load check of ``forest render`` and of the service's workers, so both see the same figures."""
    far_trees, far_triangles = None, 0
    if not variant.startswith("scalar"):
        from .render.path.from_scene import far_plan

        far_trees, far_triangles = far_plan(scene, [float(f) for f in frames])
        far_triangles += world_triangles(scene, frames, size.width)
    return render_estimate(
        size.width,
        size.height,
        size.spp,
        len(scene.instances),
        variant,
        frames=len(frames),
        subframes=size.subframes,
        triangles=unique_triangles(scene, variant),
        far_trees=far_trees,
        far_triangles=far_triangles,
    )


def largest_fitting(width: int, height: int, budget: int, estimate) -> tuple[int, int] | None:
    """The largest (w, h) of the same aspect ratio with ``estimate(w, h) <= budget``, w a multiple of 16.

    Memory grows with the image on the whole, so a bisection on the scale factor finds the edge; but not
    strictly — a smaller image packs more samples into a pass of the same lanes, so just below the edge an
    image can need a little more than one a few pixels larger.  So from the bisection's width the widths
    that are multiples of 16 are tried downwards until one fits (None when none does).
    """
    aspect = width / height
    lo, hi = 0.0, 1.0
    for _ in range(40):  # bisection on the scale factor; memory grows with it
        mid = 0.5 * (lo + hi)
        w, h = max(1, int(width * mid)), max(1, int(height * mid))
        if estimate(w, h) <= budget:
            lo = mid
        else:
            hi = mid
    for w in range(int(width * lo) // 16 * 16, 15, -16):
        h = int(round(w / aspect))
        if h >= 1 and estimate(w, h) <= budget:
            return w, h
    return None


def check_render_memory(
    config, estimate: RenderEstimate, *, available: int | Room | None = None, flags: bool = False
) -> int | None:
    """Refuse a render whose estimate exceeds the memory available; return the bytes available.

    ``available``: bytes, or a :class:`~forest.memory.Room` (the cgroup limit that binds is named in
    the error); None reads :func:`memory_room`.  The error names ``render.width``/``render.height``
    (``--width``/``--height`` when ``flags``: the size came from the command line) and the largest
    image of the same aspect ratio that fits, or says that the trees alone do not fit.
    """
    found = memory_room() if available is None else available
    if found is None:
        return None
    room = found if isinstance(found, int) else found.bytes
    if estimate.memory <= room:
        return room

    def need(w: int, h: int) -> int:
        return render_memory(
            w,
            h,
            estimate.spp,
            estimate.trees,
            estimate.variant,
            estimate.triangles,
            far_trees=estimate.far_trees,
            far_triangles=estimate.far_triangles,
        )

    trees = f" of {estimate.trees:,} trees" if estimate.trees else ""
    what = f"a {estimate.width}x{estimate.height} render{trees} needs about {format_bytes(estimate.memory)}, "
    what += _available(found)
    fits = largest_fitting(estimate.width, estimate.height, room, need)
    if fits is None and estimate.trees:
        # The trees alone do not fit: how many would, at the same share of far-level trees.
        fixed = need(64, 36) - tree_bytes(
            estimate.trees, estimate.variant, far_trees=estimate.far_trees, far_triangles=estimate.far_triangles
        )
        each = (need(64, 36) - fixed) / estimate.trees
        can = int(max(0, room - fixed) / each) if each > 0 else 0
        kept = f"about {can:,} trees fit" if can > 0 else "no trees fit"
        message = (
            what + f"; even a small image does not fit: {kept} (render fewer trees, or a smaller saved InstanceSet)"
        )
        if _kind(estimate.variant) == "jit":
            if config.lod.mode == "pixels":
                message += "; or raise [lod] pixels (the last is the far level's) so more trees merge at the far level"
            else:
                message += "; or bring [lod] distances closer so more trees merge at the far level"
        raise ConfigError(config.path, "scatter.count", message)
    if fits is None:
        message = (
            what
            + "; even a small image does not fit: render fewer trees (scatter.count, or a smaller saved InstanceSet)"
        )
    else:
        message = what + f"; {fits[0]}x{fits[1]} fits"
    field = "--width/--height" if flags else "render.width/render.height"
    if flags:
        raise ForestError(f"{field}: {message}")
    raise ConfigError(config.path, field, message)


# -- measured throughput ------------------------------------------------------------------------


def _throughput_file() -> Path:
    import platformdirs

    return platformdirs.user_state_path("forest") / "throughput.json"


def _rates() -> dict:
    try:
        data = json.loads(_throughput_file().read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _rate(key: str, name: str) -> float | None:
    rec = _rates().get(key)
    try:
        value = float(rec[name])  # type: ignore[index]
    except (TypeError, KeyError, ValueError):
        return None
    return value if math.isfinite(value) and value >= 0 else None


def _record(key: str, rates: dict[str, float]) -> None:
    """Store ``rates`` under ``key`` in the user's throughput file; never fails (it only informs estimates)."""
    path = _throughput_file()
    try:
        data = _rates()
        data[key] = rates
        from .atomic import atomic_path

        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    except (OSError, ValueError, ForestError):
        pass


def throughput(variant: str) -> tuple[float, float, bool]:
    """(seconds per camera sample, seconds per tree, measured?) of a render in ``variant`` on this machine.

    A recorded rate counts only when it came from a render of at least :data:`RECORD_MIN_SAMPLES` samples."""
    kind = _kind(variant)
    key = f"render:{variant}"
    sample_s, tree_s, samples = _rate(key, "sample_s"), _rate(key, "tree_s"), _rate(key, "samples")
    if sample_s and tree_s is not None and samples is not None and samples >= RECORD_MIN_SAMPLES:
        return sample_s, tree_s, True
    cores = max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
    scale = 2.0 / cores if kind == "scalar" else 1.0
    return SECONDS_PER_SAMPLE[kind] * scale, SECONDS_PER_TREE[kind], False


#: Recorded rates from renders with fewer camera samples do not set the forecast: their time is mostly
#: fixed cost (kernel compilation, the coverage pass), and a 32×24 test render's seconds per sample
#: forecast hours for a frame.
RECORD_MIN_SAMPLES = 1 << 20


def record_render(variant: str, *, samples: int, trees: int, render_seconds: float, load_seconds: float) -> None:
    """Remember this machine's render rates from a finished render (for the next estimate).

    A render under :data:`RECORD_MIN_SAMPLES` samples is recorded only where no larger one is, so a
    test render never replaces a real one's rates (and :func:`throughput` does not use it)."""
    if samples <= 0 or render_seconds <= 0:
        return
    key = f"render:{variant}"
    kept = _rate(key, "samples")
    if samples < RECORD_MIN_SAMPLES and kept is not None and kept >= RECORD_MIN_SAMPLES:
        return
    rates = {
        "sample_s": render_seconds / samples,
        "tree_s": load_seconds / trees if trees > 0 else 0.0,
        "samples": float(samples),
    }
    _record(key, rates)


#: Look-dev: seconds per fitted sample (optimiser pixels × spp × iterations) and the fit's memory, measured on
#: the 2-core machine (96x54 x 8 spp, 400 trees, aligned: 5.6 s per iteration under load; 0.8–1.2 GiB peak).
MATCH_SECONDS_PER_SAMPLE = 1.0e-4
MATCH_BYTES = int(1.2 * GiB)


def match_estimate(width: int, height: int, spp: int, iterations: int, variant: str, mode: str) -> tuple[float, int]:
    """(seconds, bytes) of a look-dev fit: this machine's last fit's rate if it has one, else the built-in rate."""
    rate = _rate(f"match:{variant}:{mode}", "sample_s") or MATCH_SECONDS_PER_SAMPLE
    samples = int(width) * int(height) * int(spp) * int(iterations)
    return samples * rate, MATCH_BYTES


def record_match(variant: str, mode: str, *, samples: int, seconds: float) -> None:
    """Remember this machine's look-dev rate from a finished fit."""
    if samples > 0 and seconds > 0:
        _record(f"match:{variant}:{mode}", {"sample_s": seconds / samples})


# -- formatting ---------------------------------------------------------------------------------


def format_bytes(n: float) -> str:
    """``n`` bytes in the largest binary unit it reaches, KiB to TiB: ``1.5 GiB``."""
    for unit, scale in (("TiB", 1 << 40), ("GiB", GiB), ("MiB", 1 << 20)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n / 1024:.0f} KiB"


def format_seconds(s: float) -> str:
    """A duration for an estimate: whole seconds under 90 s, minutes under 90 min, else hours to one decimal."""
    if s < 90:
        return f"{max(1, round(s))} s"
    if s < 90 * 60:
        return f"{round(s / 60)} min"
    return f"{s / 3600:.1f} h"
