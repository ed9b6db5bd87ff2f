"""The memory this process may still allocate: the machine's room and its cgroups' limits.

:func:`memory_room` is the one reader; the render pre-flight check
(:func:`forest.preflight.available_memory`) and forest_path's level-of-detail
memory plan (:func:`forest.render.path.geometry.available_bytes`) both use it.
The room is the least of

* ``MemAvailable`` in ``/proc/meminfo``: the machine's free memory and what the
  kernel can reclaim without swapping;
* for every level of the process's memory cgroup, from its own group (as
  ``/proc/self/cgroup`` names it: cgroup v2's ``0::/path`` line, cgroup v1's
  ``N:memory:/path``) up through each parent to the root of the mounted
  hierarchy, the limit less the usage: v2 ``memory.max`` − ``memory.current``
  (``max``: no limit), v1 ``memory.limit_in_bytes`` − ``memory.usage_in_bytes``
  (a value of 2⁶⁰ or more: no limit).  The usage leaves out the inactive page
  cache (``inactive_file`` in ``memory.stat``, v1 ``total_inactive_file``), which
  the kernel reclaims before it kills; a missing usage file counts as none in use.

The kernel kills a process that goes over any of these limits (Slurm jobs,
``systemd-run -p MemoryMax=``, containers), whatever the machine has free; so the
smallest wins, and :class:`Room` says which level bound it.  The hierarchies are
found through ``/proc/self/mountinfo`` (``cgroup2`` mounts, and ``cgroup`` mounts
with the ``memory`` controller) rather than assumed at ``/sys/fs/cgroup``; a
mount whose root is a group (a container without its own cgroup namespace) maps
the process's path below that root.  Limits above what the mount shows (a
container's parents on the host) are not seen.

Linux only: elsewhere, or where nothing can be read, the room is None.  The
``proc`` and ``root`` parameters (``/proc`` and the root the mount points are
under) let tests build the files in a folder of their own.
"""

from __future__ import annotations

import posixpath
import re
from dataclasses import dataclass
from pathlib import Path

#: A cgroup v1 limit at or above this is "no limit" (the kernel's is 2⁶³ less a page).
V1_UNLIMITED = 1 << 60

PROC = Path("/proc")
ROOT = Path("/")


@dataclass(frozen=True)
class CgroupLimit:
    """One level of the process's memory cgroup that has a limit."""

    path: str  # the group as /proc/self/cgroup names it, e.g. "/user.slice/user-1000.slice/job.scope"
    version: int  # 1 or 2
    limit: int  # bytes
    usage: int  # bytes in use, without the inactive page cache

    @property
    def room(self) -> int:
        """Bytes left under this level's limit."""
        return max(0, self.limit - self.usage)


@dataclass(frozen=True)
class Room:
    """Bytes this process may still allocate, and the cgroup level whose limit set it (None: the machine)."""

    bytes: int
    cgroup: CgroupLimit | None = None


def meminfo_available(proc: Path = PROC) -> int | None:
    """``MemAvailable`` in ``proc/meminfo``, in bytes; None where it cannot be read."""
    try:
        for line in (proc / "meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _unescape(field: str) -> str:
    r"""A mountinfo path with its octal escapes (``\040`` for a space) decoded."""
    return re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), field)


def _mounts(proc: Path) -> list[tuple[int, str, str]]:
    """(cgroup version, mount root, mount point) of every memory cgroup hierarchy mounted."""
    try:
        text = (proc / "self" / "mountinfo").read_text()
    except OSError:
        return []
    found = []
    for line in text.splitlines():
        left, sep, right = line.partition(" - ")
        a, b = left.split(), right.split()
        if not sep or len(a) < 5 or not b:
            continue
        options = b[2].split(",") if len(b) > 2 else []
        if b[0] == "cgroup2":
            found.append((2, _unescape(a[3]), _unescape(a[4])))
        elif b[0] == "cgroup" and "memory" in options:
            found.append((1, _unescape(a[3]), _unescape(a[4])))
    return found


def _own_groups(proc: Path) -> dict[int, str]:
    """The process's group in the v2 hierarchy and the v1 memory hierarchy: {version: path}."""
    try:
        text = (proc / "self" / "cgroup").read_text()
    except OSError:
        return {}
    groups: dict[int, str] = {}
    for line in text.splitlines():
        parts = line.split(":", 2)
        if len(parts) != 3 or not parts[2].startswith("/"):
            continue
        if parts[0] == "0" and parts[1] == "":
            groups[2] = parts[2]
        elif "memory" in parts[1].split(","):
            groups[1] = parts[2]
    return groups


def _under(path: str, top: str) -> str | None:
    """``path`` relative to ``top`` ("." for itself), or None when it is not below it."""
    if top == "/" or path == top or path.startswith(top.rstrip("/") + "/"):
        return posixpath.relpath(path, top)
    return None


def _levels(version: int, path: str, proc: Path, root: Path) -> list[tuple[str, Path]]:
    """(group path, folder) of the group ``path`` and each parent up to the top of its mount."""
    mounts = [(top, point) for v, top, point in _mounts(proc) if v == version]
    below = [(rel, top, point) for top, point in mounts if (rel := _under(path, top)) is not None]
    if below:  # the mount whose root is the process's nearest ancestor
        rel, top, point = max(below, key=lambda m: len(m[1]))
    elif mounts:  # the mount's root is no ancestor of the process's group (a namespace's "/.."): its top only
        return [(path, root / mounts[0][1].lstrip("/"))]
    else:
        return []
    base = root / point.lstrip("/")
    parts = [] if rel == "." else rel.split("/")
    return [(posixpath.join(top, *parts[:n]), base.joinpath(*parts[:n])) for n in range(len(parts), -1, -1)]


def own_cgroups(proc: Path = PROC, root: Path = ROOT) -> dict[int, list[tuple[str, Path]]]:
    """The process's memory cgroups by version (2, then 1): every level's path (as ``/proc/self/cgroup``
    names it) and folder, from its own group up to the top of the mounted hierarchy."""
    found = {}
    for version, path in sorted(_own_groups(proc).items(), reverse=True):
        levels = _levels(version, path, proc, root)
        if levels:
            found[version] = levels
    return found


def _read_int(file: Path) -> int | None:
    try:
        return int(file.read_text().strip())
    except (OSError, ValueError):
        return None


def _stat(file: Path, *keys: str) -> int:
    """The first of ``keys`` found in a ``memory.stat`` file, else 0."""
    try:
        rows = dict(line.split(maxsplit=1) for line in file.read_text().splitlines() if " " in line)
    except (OSError, ValueError):
        return 0
    for key in keys:
        try:
            return int(rows[key])
        except (KeyError, ValueError):
            continue
    return 0


def _limit(version: int, group: str, folder: Path) -> CgroupLimit | None:
    """The limit of one level, or None where it has none (or it cannot be read)."""
    inactive: tuple[str, ...]
    if version == 2:
        try:
            text = (folder / "memory.max").read_text().strip()
        except OSError:
            return None
        if text == "max" or not text.isdigit():
            return None
        limit, usage_file, inactive = int(text), "memory.current", ("inactive_file",)
    else:
        value = _read_int(folder / "memory.limit_in_bytes")
        if value is None or value >= V1_UNLIMITED:
            return None
        limit, usage_file, inactive = value, "memory.usage_in_bytes", ("total_inactive_file", "inactive_file")
    usage = _read_int(folder / usage_file) or 0
    usage = max(0, usage - _stat(folder / "memory.stat", *inactive))
    return CgroupLimit(path=group, version=version, limit=limit, usage=usage)


def cgroup_limits(proc: Path = PROC, root: Path = ROOT) -> list[CgroupLimit]:
    """Every level of the process's memory cgroups (v2 and v1) that has a limit, own group first."""
    found = []
    for version, levels in own_cgroups(proc, root).items():
        for group, folder in levels:
            limit = _limit(version, group, folder)
            if limit is not None:
                found.append(limit)
    return found


def memory_room(proc: Path = PROC, root: Path = ROOT) -> Room | None:
    """The bytes this process may still allocate (see the module docstring); None where nothing can be read."""
    machine = meminfo_available(proc)
    limits = cgroup_limits(proc, root)
    tightest = min(limits, key=lambda c: c.room, default=None)
    if tightest is not None and (machine is None or tightest.room < machine):
        return Room(tightest.room, tightest)
    return Room(machine) if machine is not None else None


def available_bytes(proc: Path = PROC, root: Path = ROOT) -> int | None:
    """:func:`memory_room` in bytes alone."""
    room = memory_room(proc, root)
    return None if room is None else room.bytes
