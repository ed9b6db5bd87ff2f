"""Atomic output files: write to a temporary name beside the target, then rename.

A failed run therefore leaves neither a half-written file nor an empty one.
A run killed outright (``kill -9``, a lost node) cannot remove its temporary;
temporaries are therefore named after their owner, ``.<name>.forest-<host>-<pid>.…tmp…``,
and the next write of the same output on the same host removes those whose
process is gone (:func:`_remove_stale`) — a live writer's are never touched,
nor another host's.
The file system's own refusals (a read-only folder, a file where a folder
should be, a folder where the file should go, a full disk) raise
:class:`~forest.errors.ForestError` naming the output, never a bare
``OSError``; :mod:`forest.preflight` checks the same before any work starts.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import socket
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .errors import ForestError

#: Errors of the storage itself while writing (full disk, quota, file size limit).
STORAGE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


def _refused(dest: Path, e: OSError) -> ForestError:
    """One line for an output the file system refuses."""
    if isinstance(e, IsADirectoryError) or dest.is_dir():
        return ForestError(f"{dest}: is a folder; cannot write a file there")
    if isinstance(e, (FileExistsError, NotADirectoryError)):
        for parent in dest.parents:
            if parent.exists() and not parent.is_dir():
                return ForestError(f"{dest}: {parent} is a file, not a folder")
    reason = e.strerror or str(e)
    if e.errno in STORAGE_ERRNOS or (e.errno == errno.EXDEV and no_space(dest.parent)):
        # A full disk can surface as the rename of a temporary that could not be completed (EXDEV): say so.
        reason = os.strerror(errno.ENOSPC) if no_space(dest.parent) else reason
    return ForestError(f"{dest}: cannot write: {reason}")


def no_space(folder: str | Path) -> bool:
    """Whether ``folder``'s file system has (almost) no space left: what a writer that reports no errno meant."""
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < 1 << 20


def _owner() -> str:
    """This process's tag in temporary names: ``forest-<host>-<pid>`` (the host's dots and dashes kept out)."""
    host = socket.gethostname().replace(".", "_").replace("-", "_") or "host"
    return f"forest-{host}-{os.getpid()}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # someone else's process: alive
    return True


def _remove_stale(folder: Path, prefix: str) -> None:
    """Remove ``folder``'s temporaries ``<prefix>forest-<this host>-<pid>.…`` whose process has exited."""
    host = _owner().rsplit("-", 1)[0]
    try:
        names = os.listdir(folder)
    except OSError:
        return
    for name in names:
        if not name.startswith(prefix + host + "-") or ".tmp" not in name:
            continue
        pid = name[len(prefix + host) + 1 :].split(".", 1)[0]
        if not pid.isdigit() or _alive(int(pid)):
            continue
        path = folder / name
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
        except OSError:
            pass  # someone else's leftovers we may not remove: leave them


def _make_parent(dest: Path) -> None:
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _refused(dest, e) from None


@contextlib.contextmanager
def atomic_path(dest: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``dest``; on success rename it onto ``dest``.

    The temporary file keeps ``dest``'s extension (image writers pick the format
    from it).  On any exception the temporary file is removed and ``dest`` is
    left untouched.
    """
    dest = Path(dest)
    if dest.is_dir():
        raise ForestError(f"{dest}: is a folder; cannot write a file there")
    if os.path.exists(dest) and not dest.is_file():  # a device, pipe or socket: never replace the node itself
        raise ForestError(f"{dest}: is not a regular file; cannot write a file there")
    _make_parent(dest)
    suffix = dest.suffix if suffix is None else suffix
    _remove_stale(dest.parent, f".{dest.stem}.")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{dest.stem}.{_owner()}.", suffix=f".tmp{suffix}", dir=dest.parent)
    except OSError as e:
        raise _refused(dest, e) from None
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        try:
            yield tmp_path
        except OSError as e:
            if e.errno in STORAGE_ERRNOS:  # the disk, not the code: name the output, not the temporary
                raise ForestError(f"{dest}: cannot write: {e.strerror}") from None
            raise
        if not tmp_path.exists() or tmp_path.stat().st_size == 0:
            raise OSError(f"{dest}: nothing was written")
        os.chmod(tmp_path, 0o644)
        try:
            os.replace(tmp_path, dest)
        except OSError as e:
            raise _refused(dest, e) from None
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def atomic_dir(dest: str | Path) -> Iterator[Path]:
    """Yield a temporary directory next to ``dest``; on success move its files into ``dest``.

    Files are moved one by one with :func:`os.replace`, so each is atomic; the
    directory is created only if something was written.
    """
    dest = Path(dest)
    if os.path.lexists(dest) and not dest.is_dir():
        raise ForestError(f"{dest}: exists and is not a folder")
    _make_parent(dest)
    _remove_stale(dest.parent, f".{dest.name}.")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.{_owner()}.", suffix=".tmp", dir=dest.parent))
    except OSError as e:
        raise _refused(dest, e) from None
    try:
        try:
            yield tmp
        except ForestError as e:  # name the output, not the temporary folder it was being written into
            raise ForestError(str(e).replace(str(tmp), str(dest))) from None
        files = sorted(p for p in tmp.rglob("*") if p.is_file())
        for p in files:
            target = dest / p.relative_to(tmp)
            try:
                target.parent.mkdir(parents=True, exist_ok=True)
                os.chmod(p, 0o644)
                os.replace(p, target)
            except OSError as e:
                raise _refused(target, e) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
