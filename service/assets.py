"""The data folder, asset names and upload checks.

Layout of a data folder::

    jobs.sqlite3            the store (WAL)
    assets/                 uploaded maps, meshes and reference photos (folders kept: maps/height.png)
    workers/                the local workers' folders and logs
    configs/                example scene configs offered by the web page (optional)
    jobs/<id>/              one folder per job: its config, linked assets, outputs, log

A job's config names its assets by paths relative to its own folder, exactly as a
config on disk names paths relative to the file.  At submission every string in the
config that looks like a file path is checked: it must be relative, must not climb
(``..``), and must name a file inside ``assets/`` (after resolving symlinks).  The file
is then hard-linked (or copied) into the job's folder under the same relative path, so
each job is self-contained and later uploads cannot change it.

Uploads are accepted only when they decode as the CLI decodes an input image
(:func:`forest.images.read_image`: the whole file, finite values) or trimesh reads them as
a mesh with finite vertices and some surface area; anything else is refused before it is
stored, in the CLI's words, naming the upload (``maps/colour.png: cannot read image: …``).
A USD stage (``[camera] usd = "shot.usda"``) must open as one USD layer (:func:`check_usd`),
hold a camera, stay under :data:`USD_MAX_BYTES` and name no other file.

An upload is hostile until checked: a 1 MB PNG can declare 16384×16000 RGBA pixels (4 GiB
decoded as float32).  So the check never runs in the service process
(:func:`check_isolated`): a child process reads the file's header first and refuses an image
whose decoded size (width × height × channels × 4 bytes, the reader's float32) is over the
decode budget (:attr:`forest.service.jobs.Limits.max_decoded_bytes`) before anything is
decoded, and only then decodes it, under an address-space limit (``RLIMIT_AS``, from
:func:`check_memory_limit`), a CPU-time limit and a wall-clock timeout.  A file that still
exhausts the child only kills the child: the upload is refused with one line and nothing
of it is stored.  Uploads are streamed to a hidden ``.upload.*`` file beside their
destination and renamed into place only once checked; a service killed meanwhile leaves
that file, which :func:`remove_partial_uploads` deletes at the next start.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path, PurePosixPath
from typing import IO

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr")
MESH_EXTS = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")
USD_EXTS = (".usda", ".usdc", ".usd")  # a camera's stage ([camera] usd)
ASSET_EXTS = IMAGE_EXTS + MESH_EXTS + USD_EXTS
#: Largest USD stage an upload may be (a camera's stage is kilobytes; a scene's worth is refused).
USD_MAX_BYTES = 16 << 20
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
MAX_DEPTH = 8  # folders in an asset's name


class AssetError(Exception):
    """A bad asset name, path or upload; ``status`` is the HTTP status to answer with."""

    def __init__(self, message: str, status: int = 422):
        super().__init__(message)
        self.status = status


class DataDir:
    """Paths inside the service's data folder."""

    def __init__(self, root: str | Path):
        self.root = Path(root).resolve()
        self.assets = self.root / "assets"
        self.jobs = self.root / "jobs"
        self.configs = self.root / "configs"
        self.workers = self.root / "workers"
        for p in (self.root, self.assets, self.jobs):
            p.mkdir(parents=True, exist_ok=True)
        self.db = self.root / "jobs.sqlite3"

    def lock(self) -> IO[str] | None:
        """Hold an exclusive lock on the data folder (one service per folder); None if another holds it.

        Returns the open lock file; the lock lasts while it stays open (and dies with the process).
        """
        import fcntl

        f = open(self.root / "service.lock", "a+")
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            return None
        return f

    def job_dir(self, job_id: str) -> Path:
        """The folder of job ``job_id`` (32 hex digits; anything else is a 404 ``AssetError``)."""
        if not re.fullmatch(r"[0-9a-f]{32}", job_id):
            raise AssetError(f"bad job id {job_id!r}", 404)
        return self.jobs / job_id

    def asset_path(self, name: str, *, field: str = "asset") -> Path:
        """Resolve an asset path strictly inside ``assets/``; raise :class:`AssetError` otherwise."""
        rel = check_relative(name, field=field)
        p = (self.assets / rel).resolve()
        if not is_inside(p, self.assets):
            raise AssetError(f"{field}: {name!r} resolves outside the data folder")
        if not p.is_file():
            raise AssetError(f"{field}: asset {name!r} not found; upload it first (PUT /assets/{name})")
        return p

    def list_assets(self) -> list[dict]:
        """Every uploaded file under ``assets/`` (hidden ones skipped), sorted: name, bytes and kind."""
        out = []
        for p in sorted(self.assets.rglob("*")):
            if p.is_file() and not p.name.startswith("."):
                out.append(
                    {
                        "name": p.relative_to(self.assets).as_posix(),
                        "bytes": p.stat().st_size,
                        "kind": asset_kind(p.name),
                    }
                )
        return out


def is_inside(path: Path, root: Path) -> bool:
    """Whether ``path`` lies under ``root`` (both as given: resolve them first to follow links)."""
    try:
        path.relative_to(root)
        return True
    except ValueError:
        return False


def check_relative(name: str, *, field: str) -> PurePosixPath:
    """A relative POSIX path without ``..``, empty parts or drive letters."""
    if not isinstance(name, str) or not name or len(name) > 512 or "\x00" in name:
        raise AssetError(f"{field}: must be a non-empty relative path")
    if "\\" in name or name.startswith(("/", "~")) or re.match(r"^[A-Za-z]:", name):
        raise AssetError(f"{field}: {name!r} must be a relative path inside the data folder")
    p = PurePosixPath(name)
    if any(part in ("..", "") for part in p.parts) or name.endswith("/"):
        raise AssetError(f"{field}: {name!r} must not contain '..'")
    if p.parts and p.parts[0] == ".":
        p = PurePosixPath(*p.parts[1:]) if len(p.parts) > 1 else p
    return p


def asset_kind(name: str) -> str | None:
    """``"image"``, ``"mesh"`` or ``"usd"`` by the name's extension, None for any other."""
    ext = Path(name).suffix.lower()
    if ext in USD_EXTS:
        return "usd"
    if ext in IMAGE_EXTS:
        return "image"
    if ext in MESH_EXTS:
        return "mesh"
    return None


def collect_assets(data: dict, datadir: DataDir) -> dict[str, Path]:
    """Check every file a parsed config names; return ``{relative name: asset file}``.

    Which strings are files comes from the scene schema (:func:`forest.config.file_values`:
    its file fields and mesh species), never from what a string looks like.
    """
    from forest.config import file_values

    out: dict[str, Path] = {}
    for field, s in file_values(data):
        rel = check_relative(s, field=f"config: {field}")
        if Path(s).suffix.lower() not in ASSET_EXTS:
            raise AssetError(
                f"config: {field}: {s!r} is not an image, mesh or USD asset (expected one of {', '.join(ASSET_EXTS)})"
            )
        out[rel.as_posix()] = datadir.asset_path(rel.as_posix(), field=f"config: {field}")
    return out


def link_into(job_dir: Path, assets: dict[str, Path]) -> None:
    """Hard-link (or copy) each asset into the job folder under its relative name."""
    for rel, src in assets.items():
        dst = job_dir / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        if dst.exists():
            continue
        try:
            os.link(src, dst)
        except OSError:
            shutil.copyfile(src, dst)


# -- uploads --------------------------------------------------------------------


def check_image(path: Path, name: str | None = None, max_decoded_bytes: int | None = None) -> dict:
    """Decode with :func:`forest.images.read_image` (the CLI's reader); raise :class:`AssetError` if it fails.

    The reader's one line — ``cannot read image: <decoder's words>``, ``image contains NaN
    or infinite values (n of N)`` — is the CLI's, with the file named by ``name`` (the
    upload's name) rather than the temporary file it was streamed to.  ``max_decoded_bytes``
    bounds the decoded image (checked from the header, before decoding): a small file can hold
    an image whose decode would exhaust the server's memory.
    """
    from forest.errors import ForestError
    from forest.images import MAX_DECODED_BYTES, read_image

    limit = MAX_DECODED_BYTES if max_decoded_bytes is None else max_decoded_bytes
    try:
        data = read_image(path, what="image", max_decoded_bytes=limit)
    except ForestError as e:
        text = str(e).replace(str(path), name or path.name)
        if name is not None and text.startswith(f"{name}: "):
            text = text[len(name) + 2 :]
        status = 422 if ("NaN" in text or "limit" in text) else 415
        raise AssetError(text, status) from None
    h, w, c = data.shape
    return {"width": int(w), "height": int(h), "channels": int(c)}


def check_mesh(path: Path) -> dict:
    """Load with trimesh; refuse anything without finite vertices (within ±1e9, any unit), at least one face and
    some area."""
    import numpy as np
    import trimesh

    try:
        m = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:
        raise AssetError(f"cannot read mesh: {type(e).__name__}", 415) from None
    faces = getattr(m, "faces", None)
    verts = getattr(m, "vertices", None)
    if faces is None or verts is None or len(faces) == 0:
        raise AssetError("upload is not a mesh with triangles", 415)
    if not np.isfinite(np.asarray(verts)).all():
        raise AssetError("mesh has NaN or infinite vertices", 422)
    from forest.library.importer import MAX_COORDINATE

    far = float(np.abs(np.asarray(verts, np.float64)).max()) if len(verts) else 0.0
    if far > MAX_COORDINATE:
        raise AssetError(f"mesh has vertices up to {far:.3g}, beyond ±{MAX_COORDINATE:g}", 422)
    if not float(getattr(m, "area", 0.0)) > 0.0:
        raise AssetError("has zero surface area", 422)
    return {"vertices": int(len(verts)), "triangles": int(len(faces))}


def check_usd(path: Path) -> dict:
    """Open ``path`` as one USD layer (``pxr.Sdf.Layer.OpenAsAnonymous``: parsed, nothing it names is opened) and
    refuse it when it is over :data:`USD_MAX_BYTES`, is no USD layer, names other files (sublayers, references,
    payloads: a job's stage stands alone and reaches no file on the server) or holds no camera."""
    size = path.stat().st_size
    if size > USD_MAX_BYTES:
        raise AssetError(f"USD stage is larger than the {USD_MAX_BYTES} byte limit", 413)
    from pxr import Sdf, Tf

    try:
        layer = Sdf.Layer.OpenAsAnonymous(str(path))
    except Tf.ErrorException:
        layer = None
    if layer is None:
        raise AssetError("cannot read USD stage: not a USD layer", 415)
    names = sorted(str(d) for d in layer.GetCompositionAssetDependencies())
    if names:
        raise AssetError(
            f"USD stage names other files ({', '.join(names[:3])}); flatten it into one file (usdcat --flatten)", 422
        )
    prims: list[str] = []
    layer.Traverse(
        Sdf.Path.absoluteRootPath,
        lambda p: prims.append(str(p)) if p.IsPrimPath() and layer.GetPrimAtPath(p).typeName == "Camera" else None,
    )
    if not prims:
        raise AssetError("USD stage has no camera (a UsdGeom.Camera prim)", 422)
    return {"cameras": sorted(prims)[:16]}


def check_asset_name(name: str) -> PurePosixPath:
    """An upload's name: a relative path of up to ``MAX_DEPTH`` folders, each part plain."""
    parts = (name or "").split("/")
    if len(parts) > MAX_DEPTH + 1 or not all(NAME_RE.fullmatch(p) and p not in (".", "..") for p in parts):
        raise AssetError(
            f"asset name {name!r}: use folders and file names of letters, digits, '.', '-' or '_'"
            f" (up to 128 each, {MAX_DEPTH} folders deep), e.g. maps/height.png",
            422,
        )
    return PurePosixPath(*parts)


def remove_partial_uploads(datadir: DataDir) -> list[Path]:
    """Remove uploads a killed service left half-stored (``assets/**/.upload.*``); returns what was removed.

    Called at start-up, before any request: an upload in progress then belongs to no live process.
    """
    removed = []
    for p in sorted(datadir.assets.rglob(".upload.*")):
        if p.is_file():
            p.unlink()
            removed.append(p)
    return removed


def store_upload(
    datadir: DataDir,
    name: str,
    chunks: Iterator[bytes],
    max_bytes: int,
    max_decoded_bytes: int | None = None,
    max_check_memory: int | None = None,
) -> dict:
    """Stream an upload to a temporary file, check it, and move it to ``assets/name`` atomically.

    ``name`` may name folders (``maps/height.png``): they are kept, so a config's relative
    paths find its maps as they do beside the config on disk.  The check runs in a child
    process (:func:`check_isolated`: the decode budget ``max_decoded_bytes``, the child's
    address space ``max_check_memory``, default :func:`check_memory_limit`).
    """
    rel = check_asset_name(name)
    kind = asset_kind(name)
    if kind is None:
        raise AssetError(f"asset name {name!r}: extension must be one of {', '.join(ASSET_EXTS)}", 415)
    fd, tmp = tempfile.mkstemp(prefix=".upload.", suffix=Path(name).suffix.lower(), dir=datadir.assets)
    tmp_path = Path(tmp)
    try:
        size = 0
        with os.fdopen(fd, "wb") as f:
            for chunk in chunks:
                size += len(chunk)
                if size > max_bytes:
                    raise AssetError(f"upload is larger than the {max_bytes} byte limit", 413)
                f.write(chunk)
        if size == 0:
            raise AssetError(f"{kind} is empty", 422)
        info = check_isolated(tmp_path, kind, name, max_decoded_bytes, max_check_memory)
        os.chmod(tmp_path, 0o644)
        dest = datadir.assets / rel
        if not is_inside(dest.parent.resolve(), datadir.assets):
            raise AssetError(f"asset name {name!r}: resolves outside the data folder", 422)
        try:
            dest.parent.mkdir(parents=True, exist_ok=True)
        except OSError:
            raise AssetError(f"asset name {name!r}: a part of {rel.parent} is a file", 409) from None
        if dest.is_dir():
            raise AssetError(f"asset name {name!r}: is a folder", 409)
        os.replace(tmp_path, dest)
        return {"name": rel.as_posix(), "kind": kind, "bytes": size, **info}
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


# -- checking an upload in a child process ----------------------------------------------------

#: What a checking child may use besides the decoded image: the interpreter, numpy, OpenImageIO
#: or trimesh (≈ 300 MiB of address space measured after the imports) with room to spare.
CHECK_BASE_BYTES = 768 * 2**20
#: The decoded image counts this many times: OpenImageIO's native buffer, the float32 copy and
#: the finite-value test's masks.
CHECK_DECODED_FACTOR = 3
#: Wall-clock and CPU seconds a checking child may take (a decompression bomb is stopped too).
CHECK_TIMEOUT_S = 120.0
#: Checking children at once: more uploads wait their turn, so that parallel uploads cannot add up their
#: children's memory limits.
CHECK_CONCURRENCY = 2
_check_slots = threading.BoundedSemaphore(CHECK_CONCURRENCY)


def check_memory_limit(max_decoded_bytes: int | None = None) -> int:
    """The address space (bytes) a checking child may use: :data:`CHECK_BASE_BYTES` plus
    :data:`CHECK_DECODED_FACTOR` × the decode budget (512 MiB by default: 2.25 GiB)."""
    from forest.images import MAX_DECODED_BYTES

    decoded = MAX_DECODED_BYTES if max_decoded_bytes is None else int(max_decoded_bytes)
    return CHECK_BASE_BYTES + CHECK_DECODED_FACTOR * decoded


def _mib(n: int) -> str:
    return f"{n / 2**20:.0f} MiB"


def check_isolated(
    path: Path,
    kind: str,
    name: str | None = None,
    max_decoded_bytes: int | None = None,
    max_memory: int | None = None,
    *,
    timeout_s: float = CHECK_TIMEOUT_S,
) -> dict:
    """:func:`check_image`, :func:`check_usd` or :func:`check_mesh` of ``path`` (by ``kind``) in a child process;
    what they return or raise.

    The child limits its own address space to ``max_memory`` bytes (default
    :func:`check_memory_limit` of ``max_decoded_bytes``) and its CPU time to ``timeout_s``
    before it imports anything, and is killed after ``timeout_s`` seconds; at most
    :data:`CHECK_CONCURRENCY` children run at once.  A child that
    dies (killed by the kernel, out of memory, a decoder's crash) or overruns is one
    :class:`AssetError` (422) saying so; the service process never holds the decoded file.
    """
    memory = check_memory_limit(max_decoded_bytes) if max_memory is None else int(max_memory)
    request = {
        "path": str(path),
        "kind": kind,
        "name": name,
        "max_decoded_bytes": max_decoded_bytes,
        "max_memory": memory,
        "cpu_s": max(1, math.ceil(timeout_s)),
    }
    env = {
        **os.environ,
        # one thread each: every thread's stack and malloc arena would count against the address space
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "MALLOC_ARENA_MAX": "2",
        "PYTHONDONTWRITEBYTECODE": "1",
    }
    env.pop("PYTHONSTARTUP", None)
    what = _what(kind)
    try:
        with _check_slots:
            done = subprocess.run(
                [sys.executable, "-c", "from forest.service.assets import _check_child; _check_child()"],
                input=json.dumps(request),
                capture_output=True,
                text=True,
                timeout=timeout_s,
                env=env,
            )
    except subprocess.TimeoutExpired:
        raise AssetError(f"cannot read {what}: checking it took over {timeout_s:g} s", 422) from None
    answer = None
    for line in reversed(done.stdout.splitlines()):
        if line.startswith("{"):
            try:
                answer = json.loads(line)
            except ValueError:
                answer = None
            break
    if isinstance(answer, dict) and "info" in answer:
        return answer["info"]
    if isinstance(answer, dict) and "error" in answer:
        raise AssetError(str(answer["error"]), int(answer.get("status", 422)))
    import signal

    if done.returncode == -signal.SIGXCPU:
        raise AssetError(f"cannot read {what}: checking it took over {timeout_s:g} s of CPU", 422)
    raise AssetError(f"{_over_memory(kind, memory)} ({_ended(done.returncode)})", 422)


def _over_memory(kind: str, memory: int) -> str:
    what = _what(kind)
    return f"cannot read {what}: decoding it needs more than the {_mib(memory)} the service allows one upload's check"


def _what(kind: str) -> str:
    """An upload's kind in a message: ``image``, ``mesh`` or ``USD stage``."""
    return {"image": "image", "usd": "USD stage"}.get(kind, "mesh")


def _ended(returncode: int) -> str:
    """How a checking child ended, in words: ``the check was killed by SIGKILL``, ``… exited with status 1``."""
    if returncode < 0:
        import signal

        try:
            return f"the check was killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"the check was killed by signal {-returncode}"
    return f"the check exited with status {returncode}"


def _check_child() -> None:
    """The checking child: read the request (JSON on stdin), limit itself, check, answer one JSON line.

    The limits are set before the decoders are imported, so they bind everything the check does.
    """
    import resource

    request = json.loads(sys.stdin.read())
    memory = int(request["max_memory"])
    resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
    cpu = int(request["cpu_s"])
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
    try:
        os.nice(10)
    except OSError:
        pass
    path, name = Path(request["path"]), request["name"]
    try:
        if request["kind"] == "image":
            info = check_image(path, name, request["max_decoded_bytes"])
        elif request["kind"] == "usd":
            info = check_usd(path)
        else:
            info = check_mesh(path)
        answer: dict = {"info": info}
    except AssetError as e:
        answer = {"error": str(e), "status": e.status}
    except MemoryError:
        answer = {"error": _over_memory(request["kind"], memory), "status": 422}
    except Exception as e:  # a reader's own failure: refused, named by its kind
        answer = {"error": f"cannot read {_what(request['kind'])}: {type(e).__name__}", "status": 415}
    sys.stdout.write("\n" + json.dumps(answer) + "\n")
    sys.stdout.flush()
