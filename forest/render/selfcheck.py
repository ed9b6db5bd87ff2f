"""The GPU self-check: does forest_path render in ``cuda_ad_rgb`` on this machine, correctly and in time?

An NVIDIA driver being present (:func:`forest.runtime.cuda_available`) does
not make the GPU a safe default: a driver too old for drjit's PTX, an OptiX
or CUDA error, a kernel that hangs or an image of NaNs would each cost the
user a failed (or endless) render they did not ask the GPU for.  So the
automatic variant choice (:func:`forest.render.variant.choose_variant`,
without ``--variant`` or ``[render] variant``) takes the GPU only where this
check has passed; an explicit ``cuda_ad_rgb`` never runs it.

What it checks: forest_path (:class:`~forest.render.path.PathScene`) renders
a tiny scene — a ground quad and four instanced two-part box trees (leaves
that transmit light, bark) under a disc sun and a constant sky, seen from
above so that every camera ray hits a surface — in ``cuda_ad_rgb`` at
:data:`WIDTH`×:data:`HEIGHT`, :data:`SPP` spp.  It passes when

* the render runs in a child process (``python -m forest.render.selfcheck
  OUT.npy``, :func:`main`), so that a hang, a crash in the driver or a CUDA
  error cannot take the caller down, and ends with status 0;
* within :data:`TIME_LIMIT_S` seconds, counted from the child's start (the
  parent kills the child's process group at the bound);
* and its image (:func:`judge`) is finite everywhere, not black, covered
  (every camera ray hit the ground or a tree) and shows the trees' leaves
  (instancing works on the GPU).

The result — pass or fail, the reason, the seconds — is kept in a small JSON
file in the user cache folder (``$FOREST_CACHE_DIR``, else
``platformdirs.user_cache_path("forest")``), one entry per key: the GPU's
name, the driver version and the mitsuba and drjit versions
(:func:`machine_key`), so a new driver, GPU or Mitsuba checks again and
nothing else does.  Processes that start together (the job service's
workers) take a lock on the file, so one of them checks and the others read
its result.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..runtime import gpu_info

#: The bound on the whole check, in seconds, child start to image.  It includes starting Python and importing
#: Mitsuba and, on the first run after a new driver or Mitsuba, compiling the kernels: drjit traces forest_path, the
#: driver JIT-compiles its PTX and OptiX builds its pipeline (cached afterwards in drjit's and the driver's kernel
#: caches).  Measured on an H100 (driver 580.159.04, mitsuba 3.9.1): 6.2 s on a fresh machine, every cache empty;
#: 3.2-3.7 s after.  60 s is ten times the cold cost, room for a slower GPU or a busy machine, and bounds what a hung
#: GPU costs the first render on a machine: one minute, once per GPU, driver and Mitsuba.
TIME_LIMIT_S = 60.0
#: The check's image: 64×36 pixels (the 16:9 of forest's renders), 4 samples per pixel, paths of 3 bounces.
WIDTH, HEIGHT, SPP, MAX_DEPTH = 64, 36, 4, 3
#: Mean linear RGB at or below which the image counts as black (the check's image has about 0.24).
BLACK = 1e-3
#: The share of camera rays that must hit a surface (the ground fills the view: all of them).
MIN_COVERAGE = 0.99
#: The share of pixels that must show the trees' green leaves (green over 1.25 × red; about 8 % do in
#: ``llvm_ad_rgb``, the ground's green is 0.93 × its red): trees that the GPU's instancing lost fail.
MIN_TREES = 0.03
#: The child ends itself (SIGALRM) this long after the bound, should the parent that enforces it be gone.
ALARM_GRACE_S = 10.0
#: The file in the cache folder (:mod:`forest.cache`; ``CACHE_ENV`` moves the folder).
CACHE_NAME = "gpu-selfcheck.json"


class SelfCheckError(Exception):
    """The check could not produce an image: ``reason`` says why (a timeout, a crash, a CUDA error)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class SelfCheck:
    """One check's outcome: ``ok``, the ``reason`` (what failed, or what passed), its ``seconds``, the machine
    ``key`` it holds for and when it ran (``checked``, epoch seconds); ``cached``: read back, not run now."""

    ok: bool
    reason: str
    seconds: float
    key: dict[str, str] = field(default_factory=dict)
    checked: float = 0.0
    cached: bool = False

    def line(self) -> str:
        """One line for people: passed or failed, why, how long, when."""
        when = time.strftime("%Y-%m-%d %H:%M", time.localtime(self.checked)) if self.checked else "now"
        verdict = "passed" if self.ok else "failed"
        return (
            f"GPU self-check {verdict} ({self.reason}; {self.seconds:.1f} s, {when}{', cached' if self.cached else ''})"
        )


def machine_key() -> dict[str, str]:
    """What a result holds for: the GPU's name, the driver version, mitsuba's and drjit's versions."""
    gpu = gpu_info()

    def version(dist: str) -> str:
        try:
            return importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            return "none"

    return {
        "gpu": gpu.name if gpu is not None else "none",
        "driver": (gpu.driver if gpu is not None else None) or "unknown",
        "mitsuba": version("mitsuba"),
        "drjit": version("drjit"),
    }


def cache_path() -> Path:
    """The results file: ``$FOREST_CACHE_DIR/gpu-selfcheck.json``, else in the user cache folder."""
    from ..cache import cache_root

    return cache_root() / CACHE_NAME


# -- the child --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Part:
    """A library part's fields (:class:`forest.library.core.Part`), its mesh in memory."""

    kind: str
    colour: tuple[float, float, float]
    mesh: Any
    translucency: float = 0.0
    tinted: bool = False
    texture: None = None

    def load(self) -> Any:
        """The mesh (``MeshData``)."""
        return self.mesh


@dataclass(frozen=True)
class _Lod:
    name: str
    triangles: int
    bounds: np.ndarray
    parts: tuple[_Part, ...]


@dataclass(frozen=True)
class _Species:
    name: str
    lods: list[_Lod]


def _box(lo: Sequence[float], hi: Sequence[float]) -> Any:
    """An axis-aligned box as 12 outward-facing triangles (``MeshData``)."""
    from ..library.mesh import MeshData, vertex_normals

    corner = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    v = np.asarray(lo, np.float32) + corner * (np.asarray(hi, np.float32) - np.asarray(lo, np.float32))
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1]]
        + [[2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
        np.uint32,
    )
    return MeshData(v, f, vertex_normals(v, f).astype(np.float32), np.zeros((8, 2), np.float32))


def _ground(half: float) -> Any:
    """A horizontal square of side 2 ``half`` at height 0, facing up (``MeshData``)."""
    from ..library.mesh import MeshData

    v = np.array([[-half, 0, -half], [half, 0, -half], [half, 0, half], [-half, 0, half]], np.float32)
    f = np.array([[0, 2, 1], [0, 3, 2]], np.uint32)
    n = np.tile(np.array([[0.0, 1.0, 0.0]], np.float32), (4, 1))
    return MeshData(v, f, n, np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32))


def check_inputs(width: int = WIDTH, height: int = HEIGHT, spp: int = SPP) -> Any:
    """The check's scene as :class:`~forest.render.path.PathInputs` (see the module docstring)."""
    from ..camera import look_at_matrix
    from ..instances import InstanceSet, yaw_tilt_quaternion
    from .path import Material, PathCamera, PathInputs, SkyLight, SunLight, Surface

    crown, trunk = _box((-2.0, 2.0, -2.0), (2.0, 7.0, 2.0)), _box((-0.3, 0.0, -0.3), (0.3, 2.0, 0.3))
    parts = (_Part("leaf", (0.15, 0.45, 0.1), crown, translucency=0.3), _Part("bark", (0.35, 0.25, 0.15), trunk))
    bounds = np.array([[-2.0, 0.0, -2.0], [2.0, 7.0, 2.0]])
    species = _Species("selfcheck box", [_Lod("high", 24, bounds, parts)])
    position = np.array([[-8.0, 0.0, -5.0], [8.0, 0.0, -5.0], [-4.0, 0.0, 6.0], [10.0, 0.0, 7.0]], np.float32)
    n = len(position)
    up = np.tile(np.array([0.0, 1.0, 0.0]), (n, 1))
    yaw = np.array([0.0, 0.4, 0.9, 1.3])
    trees = InstanceSet(
        id=np.arange(n),
        position=position,
        rotation=yaw_tilt_quaternion(yaw, up, np.zeros(n)),
        yaw=yaw,
        scale=np.ones(n),
        species=np.zeros(n, np.int64),
        tint=np.ones((n, 3)),
        partition=np.zeros(n),
        normal=up,
        phase=np.zeros(n),
        species_names=[species.name],
        extent=(-50.0, -50.0, 50.0, 50.0),
    )
    ground = _ground(50.0)
    camera = PathCamera(look_at_matrix([0.0, 45.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]), 60.0, width, height)
    return PathInputs(
        instances=trees,
        species=[species],
        levels=np.zeros(n, np.int64),
        matrices=trees.matrices(),
        camera=camera,
        sun=SunLight((0.37, 0.85, 0.37), (2.5, 2.4, 2.2)),
        sky=SkyLight("constant", (0.3, 0.35, 0.45)),
        surfaces=[Surface(ground, Material("surface", (0.3, 0.28, 0.22)))],
        max_depth=MAX_DEPTH,
        spp=spp,
        flatten_triangles=0,  # instanced, as a forest's trees are
    )


def render_check(variant: str = "cuda_ad_rgb") -> np.ndarray:
    """The check's image in ``variant``: (HEIGHT, WIDTH, 4) float32, linear RGB and coverage."""
    from .path import PathScene

    img = PathScene(check_inputs(), variant).render()
    return np.concatenate([img.rgb, img.alpha[..., None]], axis=2).astype(np.float32)


def main(argv: Sequence[str] | None = None) -> int:
    """The child: render the check's image and save it to ``OUT.npy``; status 1 (and the error on stderr) when the
    render raised."""
    parser = argparse.ArgumentParser(
        prog="python -m forest.render.selfcheck", description="Render forest's GPU self-check image (a .npy)."
    )
    parser.add_argument("output", type=Path, help="the .npy to write: (H, W, 4) linear RGB and coverage")
    parser.add_argument("--variant", default="cuda_ad_rgb", choices=("cuda_ad_rgb", "llvm_ad_rgb"))
    parser.add_argument(
        "--limit", type=float, default=None, help="end (SIGALRM) after this many seconds and ALARM_GRACE_S"
    )
    args = parser.parse_args(argv)
    if args.limit is not None and hasattr(signal, "alarm"):
        # The parent kills this process at its bound; should the parent itself be killed meanwhile (a job
        # service's worker is), the alarm still ends a check that hangs.
        signal.alarm(max(1, math.ceil(args.limit + ALARM_GRACE_S)))
    t0 = time.perf_counter()
    try:
        img = render_check(args.variant)
    except Exception as e:
        print(f"selfcheck: {type(e).__name__}: {e}".strip(), file=sys.stderr, flush=True)
        return 1
    np.save(args.output, img)
    problem = judge(img)
    print(
        f"selfcheck: {args.variant} {WIDTH}x{HEIGHT} {SPP} spp in {time.perf_counter() - t0:.1f} s: {problem or 'ok'}",
        flush=True,
    )
    return 0


# -- the parent -------------------------------------------------------------------------------------


def judge(image: np.ndarray) -> str | None:
    """What is wrong with a check image ((H, W, 3) or (H, W, 4) with coverage), or None: not finite, black,
    camera rays that missed, or no trees."""
    a = np.asarray(image, np.float64)
    if a.ndim != 3 or a.shape[2] not in (3, 4) or a.size == 0:
        return f"an image of shape {a.shape}, not (H, W, 3|4)"
    bad = int((~np.isfinite(a)).any(axis=2).sum())
    if bad:
        return f"{bad} of {a.shape[0] * a.shape[1]} pixels are not finite (NaN or infinite)"
    mean = float(a[..., :3].mean())
    if mean <= BLACK:
        return f"the image is black (mean {mean:.2g})"
    if a.shape[2] == 4:
        covered = float(a[..., 3].mean())
        if covered < MIN_COVERAGE:
            return f"camera rays hit nothing in {100 * (1 - covered):.0f} % of the image (the ground fills it)"
    trees = float((a[..., 1] > 1.25 * a[..., 0]).mean())
    if trees < MIN_TREES:
        return f"the trees are missing: {100 * trees:.1f} % of the pixels show leaves, not the 8 % expected"
    return None


def _stop(proc: subprocess.Popen[str]) -> str:
    """Kill the child's process group; what it printed (as far as it can be read within 5 s)."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(ProcessLookupError):
        proc.kill()
    try:
        out, _ = proc.communicate(timeout=5)
    except subprocess.TimeoutExpired:  # stuck in the driver beyond SIGKILL: leave it
        return ""
    return out or ""


def _last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    if not lines:
        return "no output"
    line = lines[-1].removeprefix("selfcheck: ")
    return line if len(line) <= 120 else line[:117] + "..."  # the reason is printed on one line with the variant


def _ended(code: int) -> str:
    """How a process with exit status ``code`` ended, in words."""
    if code >= 0:
        return f"exited with status {code}"
    try:
        return f"was killed by {signal.Signals(-code).name}"
    except ValueError:
        return f"was killed by signal {-code}"


def launch(variant: str = "cuda_ad_rgb", *, timeout_s: float, command: Sequence[str] | None = None) -> np.ndarray:
    """Run the child and return its image; :class:`SelfCheckError` when it does not end within ``timeout_s``
    (it is killed, with its process group), exits with an error or writes no image.

    ``command``: another child to run (tests), ``{out}`` in it standing for the image's path."""
    with tempfile.TemporaryDirectory(prefix="forest-selfcheck-") as tmp:
        out = Path(tmp) / "image.npy"
        if command is None:
            cmd = [sys.executable, "-m", "forest.render.selfcheck", "--variant", variant, "--limit", f"{timeout_s:g}"]
            cmd.append(str(out))
        else:
            cmd = [c.replace("{out}", str(out)) for c in command]
        try:
            proc = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
                errors="replace",
                start_new_session=True,  # its own process group: killed whole at the bound
            )
        except OSError as e:
            raise SelfCheckError(f"cannot start the check: {e}") from None
        try:
            text, _ = proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            text = _stop(proc)
            raise SelfCheckError(f"no image within {timeout_s:g} s (killed; {_last_line(text)})") from None
        except BaseException:
            _stop(proc)
            raise
        if proc.returncode != 0:
            raise SelfCheckError(f"the check process {_ended(proc.returncode)}: {_last_line(text)}")
        try:
            return np.asarray(np.load(out), np.float64)
        except (OSError, ValueError) as e:
            raise SelfCheckError(f"the check process wrote no image ({type(e).__name__}: {e})") from None


def run_check(key: dict[str, str] | None = None, variant: str = "cuda_ad_rgb") -> SelfCheck:
    """Run the check now (no cache): :func:`launch` bounded by :data:`TIME_LIMIT_S`, then :func:`judge`."""
    limit = float(TIME_LIMIT_S)
    t0 = time.monotonic()
    try:
        problem = judge(launch(variant, timeout_s=limit))
    except SelfCheckError as e:
        problem = e.reason
    seconds = time.monotonic() - t0
    if problem is None and seconds > limit:
        problem = f"took {seconds:.1f} s, over the {limit:g} s bound"
    reason = problem or f"{variant} rendered a finite {WIDTH}x{HEIGHT} image of instanced trees"
    return SelfCheck(problem is None, reason, round(seconds, 2), dict(key or {}), time.time())


def _read(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    checks = data.get("checks") if isinstance(data, dict) else None
    return checks if isinstance(checks, dict) else {}


def _entry(checks: dict[str, Any], name: str) -> SelfCheck | None:
    rec = checks.get(name)
    if not isinstance(rec, dict):
        return None
    try:
        return SelfCheck(
            bool(rec["ok"]),
            str(rec["reason"]),
            float(rec["seconds"]),
            {str(k): str(v) for k, v in dict(rec["key"]).items()},
            float(rec.get("checked", 0.0)),
            cached=True,
        )
    except (KeyError, TypeError, ValueError):
        return None


def _write(path: Path, name: str, result: SelfCheck) -> None:
    """Add ``result`` under ``name`` to the file; never fails (an unwritable cache only means checking again)."""
    from ..atomic import atomic_path
    from ..errors import ForestError

    checks = _read(path)
    rec = asdict(result)
    rec.pop("cached")
    checks[name] = rec
    with contextlib.suppress(OSError, ValueError, ForestError), atomic_path(path) as tmp:
        tmp.write_text(json.dumps({"checks": checks}, indent=1, sort_keys=True) + "\n")


@contextlib.contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``path`` + ``.lock`` (other processes wait); nothing where it cannot be taken."""
    try:
        import fcntl

        path.parent.mkdir(parents=True, exist_ok=True)
        f = open(path.with_name(path.name + ".lock"), "a")
    except (ImportError, OSError):
        yield
        return
    with f:
        try:
            fcntl.flock(f, fcntl.LOCK_EX)
        except OSError:
            pass
        yield


def key_name(key: dict[str, str]) -> str:
    """The key as the file names it."""
    return json.dumps(key, sort_keys=True, separators=(",", ":"))


_lock = threading.Lock()
_memo: dict[str, SelfCheck] = {}


def cached_check() -> SelfCheck | None:
    """This machine's stored result (for its current key), or None when it has not been checked."""
    return _entry(_read(cache_path()), key_name(machine_key()))


def pending() -> bool:
    """True when :func:`gpu_selfcheck` would run the check now (no result remembered or stored for this machine)."""
    name = key_name(machine_key())
    return name not in _memo and _entry(_read(cache_path()), name) is None


def gpu_selfcheck(*, refresh: bool = False) -> SelfCheck:
    """This machine's result: remembered by the process, else read from the cache file, else run now (once for all
    processes that ask together) and stored.  ``refresh``: run it again."""
    key = machine_key()
    name = key_name(key)
    with _lock:
        if not refresh and name in _memo:
            return _memo[name]
        path = cache_path()
        with _file_lock(path):
            hit = None if refresh else _entry(_read(path), name)
            if hit is None:
                hit = run_check(key)
                _write(path, name, hit)
        _memo[name] = hit
        return hit


if __name__ == "__main__":
    sys.exit(main())
