"""Moving a job's files between the service and workers that do not share its disk.

Inputs are content-addressed: at submission every file a job reads gets the SHA-256
of its bytes (:func:`file_sha256`, cached by inode, size and mtime so a map used by a
thousand jobs is hashed once).  A worker keeps a :class:`BlobStore` of the blobs it has
fetched and lays each task's inputs out in a folder of their own (:meth:`BlobStore.inputs`)
— the config's relative paths resolve there exactly as in the job folder.  The folder's
name is the hash of the (name → blob) table, so tasks with the same inputs share it.

Outputs travel back inside reports (``files``: job-relative path → bytes); the
dispatcher writes them with :func:`write_shipped` (atomically, inside the job folder).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import tempfile
import threading
from collections.abc import Callable, Mapping
from pathlib import Path

from .assets import check_relative, is_inside
from .models import digest

_hash_cache: dict[tuple[int, int, int, int], str] = {}
_hash_lock = threading.Lock()


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes (remembered per device, inode, size and mtime)."""
    st = path.stat()
    key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    with _hash_lock:
        hit = _hash_cache.get(key)
    if hit is not None:
        return hit
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    value = h.hexdigest()
    with _hash_lock:
        if len(_hash_cache) > 100_000:
            _hash_cache.clear()
        _hash_cache[key] = value
    return value


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


class BlobStore:
    """A worker's own content-addressed files: ``blobs/<sha256>`` and input folders built from them."""

    def __init__(self, root: Path, *, keep_inputs: int = 32):
        self.root = Path(root)
        self.blobs = self.root / "blobs"
        self.folders = self.root / "inputs"
        self.blobs.mkdir(parents=True, exist_ok=True)
        self.folders.mkdir(parents=True, exist_ok=True)
        self.keep_inputs = keep_inputs
        self.remove_partial()

    def remove_partial(self, older_than_s: float = 60.0) -> list[Path]:
        """Remove what a killed worker left half-written (``blobs/.blob.*``, ``blobs/.link.*``,
        ``inputs/.build.*``) over ``older_than_s`` seconds ago; returns what was removed.

        A blob is written in one go and an input folder built in seconds, so an older one belongs to no
        live process; a half-written blob is never taken for a stored one (only ``blobs/<sha256>`` is).
        """
        import time

        now = time.time()
        removed = []
        for pattern, folder in ((".blob.*", self.blobs), (".link.*", self.blobs), (".build.*", self.folders)):
            for p in folder.glob(pattern):
                try:
                    if now - p.lstat().st_mtime < older_than_s:
                        continue
                    if p.is_dir() and not p.is_symlink():
                        shutil.rmtree(p, ignore_errors=True)
                    else:
                        p.unlink()
                    removed.append(p)
                except OSError:
                    pass
        return removed

    def path(self, sha: str) -> Path:
        """Where blob ``sha`` is (or would be) stored."""
        return self.blobs / sha

    def has(self, sha: str) -> bool:
        """Whether blob ``sha`` is stored."""
        return self.path(sha).is_file()

    def put_bytes(self, sha: str, data: bytes) -> Path:
        """Store ``data`` as blob ``sha`` (checked: a corrupt transfer never enters the store)."""
        if hashlib.sha256(data).hexdigest() != sha:
            raise OSError(f"blob {sha[:12]}: content does not match its hash")
        dst = self.path(sha)
        if not dst.exists():
            fd, tmp = tempfile.mkstemp(dir=self.blobs, prefix=".blob.")
            try:
                with os.fdopen(fd, "wb") as f:
                    f.write(data)
                os.replace(tmp, dst)
            except BaseException:
                Path(tmp).unlink(missing_ok=True)
                raise
        return dst

    def put_file(self, sha: str, src: Path) -> Path:
        """Store a local file (hard link when possible) as blob ``sha``."""
        dst = self.path(sha)
        if not dst.exists():
            tmp = self.blobs / f".link.{os.getpid()}.{threading.get_ident()}.{sha}"
            try:
                _link_or_copy(src, tmp)
                os.replace(tmp, dst)
            except BaseException:
                tmp.unlink(missing_ok=True)
                raise
        return dst

    def relative(self, text: str, *folders: Path) -> str:
        """``text`` with the places of a task's files (its inputs folder, ``folders``) cut: files as the job names them.

        A user's mistake is reported against ``sky.exr``, the name in the config, not the
        worker's copy of it.
        """
        text = re.sub(re.escape(str(self.folders)) + r"/[^/\s]+/", "", text)
        for folder in folders:
            text = text.replace(f"{folder}/", "")
        return text

    def inputs(self, table: Mapping[str, str], fetch: Callable[[str, str], Path]) -> Path:
        """A folder holding every input under its job-relative name; ``fetch(rel, sha)`` gives a missing blob.

        Built once per distinct table (in a temporary folder renamed into place), reused after.
        """
        folder = self.folders / digest(dict(table))[:32]
        if folder.is_dir():
            os.utime(folder)
            return folder
        tmp = Path(tempfile.mkdtemp(dir=self.folders, prefix=".build."))
        try:
            for rel, sha in sorted(table.items()):
                name = check_relative(rel, field="input")
                blob = self.path(sha) if self.has(sha) else self.put_file(sha, fetch(rel, sha))
                _link_or_copy(blob, tmp / name)
            try:
                os.rename(tmp, folder)
            except OSError:  # built meanwhile by another worker: use that one
                shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        self._evict()
        return folder

    def _evict(self) -> None:
        folders = sorted(
            (p for p in self.folders.iterdir() if p.is_dir() and not p.name.startswith(".")),
            key=lambda p: p.stat().st_mtime,
        )
        for p in folders[: max(0, len(folders) - self.keep_inputs)]:
            shutil.rmtree(p, ignore_errors=True)


def read_files(root: Path, rels: list[str]) -> dict[str, bytes]:
    """The bytes of job-relative files under ``root`` (for shipping with a report)."""
    return {rel: (root / rel).read_bytes() for rel in rels if (root / rel).is_file()}


def write_shipped(job_dir: Path, files: Mapping[str, bytes]) -> list[str]:
    """Write shipped files into the job folder atomically; refuse paths that leave it."""
    root = job_dir.resolve()
    written = []
    for rel, data in files.items():
        name = check_relative(rel, field="file")
        dst = (root / name).resolve()
        if not is_inside(dst, root):
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=dst.parent, prefix=f".{dst.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.chmod(tmp, 0o644)
            os.replace(tmp, dst)
        except BaseException:  # a full disk: no half-written output stays beside the outputs
            Path(tmp).unlink(missing_ok=True)
            raise
        written.append(name.as_posix())
    return written
