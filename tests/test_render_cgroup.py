"""``forest render`` in a small memory cgroup that the test makes: the pre-flight check sees the group's limit.

A 1 GiB limit (a Slurm job's, ``systemd-run -p MemoryMax=1G``'s, a container's) on a machine with far more
free: a 4096×2160 render is refused before rendering with one line naming the cgroup and exit status 2 —
not started and then killed by the kernel (137) — and a small render in the same group renders.

The group is made under the process's own memory cgroup: cgroup v2 where its memory controller is enabled
(a sibling of the process's group, or a child of the hierarchy's root, enabling ``memory`` in the root's
``cgroup.subtree_control`` if it must), else cgroup v1's memory hierarchy.  The render joins it from a
shell that writes its own pid into ``cgroup.procs`` and then execs ``forest``.  The test skips, saying why,
where it cannot make the group (not root, a read-only cgroupfs, no memory controller delegated).
"""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from test_render_cli import SCENE as CLI_SCENE

from forest.memory import own_cgroups

ROOT = Path(__file__).resolve().parents[1]
GiB = 1 << 30
LIMIT = GiB

#: The render CLI tests' scene (terrain, two species, sun and sky, LOD bands) at 160×90, 4 spp.
SCENE = CLI_SCENE.format(render="").replace("width = 32\nheight = 24\nspp = 2\n", "width = 160\nheight = 90\nspp = 4\n")
assert "width = 160" in SCENE


class Group:
    """A memory cgroup made for the test: its folder, version and path (as /proc/self/cgroup names it)."""

    def __init__(self, folder: Path, version: int, path: str):
        self.folder, self.version, self.path = folder, version, path

    def peak(self) -> int | None:
        """The group's peak usage in bytes, where the kernel keeps it."""
        name = "memory.peak" if self.version == 2 else "memory.max_usage_in_bytes"
        try:
            return int((self.folder / name).read_text())
        except (OSError, ValueError):
            return None

    def run(self, *args: object, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
        """``forest ARGS`` in this group: a shell moves itself in, then execs the CLI."""
        join = 'echo $$ > "$0/cgroup.procs" && exec "$@"'
        cmd = ["sh", "-c", join, str(self.folder), sys.executable, "-m", "forest.cli", *map(str, args)]
        return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env, timeout=600)


def _write(path: Path, value: str) -> None:
    path.write_text(value)


def _v2_parent(levels: list[tuple[str, Path]]) -> tuple[str, Path, bool]:
    """Where a v2 group with the memory controller can be made: (path, folder, memory enabled there by us)."""
    top = levels[-1][1]
    if "memory" not in (top / "cgroup.controllers").read_text().split():
        pytest.skip("cgroup v2 is mounted without the memory controller (it is bound to a v1 hierarchy)")
    own_path, own = levels[0]
    if (own / "memory.max").is_file() and len(levels) > 1:
        return levels[1][0], levels[1][1], False  # memory is enabled for the process's group: make a sibling
    if len(levels) > 1:
        pytest.skip(f"the memory controller is not delegated to {own_path} (none of its memory.* files)")
    if "memory" in (own / "cgroup.subtree_control").read_text().split():
        return own_path, own, False
    _write(own / "cgroup.subtree_control", "+memory")  # the hierarchy's root may hold processes and controllers
    return own_path, own, True


@contextlib.contextmanager
def memory_group(limit: int) -> Iterator[Group]:
    """A fresh memory cgroup limited to ``limit`` bytes (no swap), removed afterwards; skips where none can be made."""
    groups = own_cgroups()
    if not groups:
        pytest.skip("no memory cgroup hierarchy found in /proc/self/cgroup and /proc/self/mountinfo")
    name = f"forest-test-{os.getpid()}-{time.monotonic_ns()}"
    enabled: Path | None = None
    if 2 in groups and "memory" in (groups[2][-1][1] / "cgroup.controllers").read_text().split():
        parent_path, parent, ours = _v2_parent(groups[2])
        enabled = parent if ours else None
        version, limit_file, swap_file = 2, "memory.max", "memory.swap.max"
    elif 1 in groups:
        parent_path, parent = groups[1][0]
        version, limit_file, swap_file = 1, "memory.limit_in_bytes", "memory.memsw.limit_in_bytes"
    else:
        pytest.skip("cgroup v2 is mounted without the memory controller and there is no v1 memory hierarchy")
    folder = parent / name
    try:
        folder.mkdir()
    except OSError as e:
        who = "" if os.geteuid() == 0 else " (not root)"
        reason = "read-only cgroupfs" if e.errno == errno.EROFS else (e.strerror or str(e))
        if enabled is not None:
            with contextlib.suppress(OSError):
                _write(enabled / "cgroup.subtree_control", "-memory")
        pytest.skip(f"cannot make a cgroup under {parent}{who}: {reason}")
    try:
        _write(folder / limit_file, str(limit))
        value = "0" if version == 2 else str(limit)  # v1: memory+swap no more than memory alone
        with contextlib.suppress(OSError):
            _write(folder / swap_file, value)
        yield Group(folder, version, f"{parent_path.rstrip('/')}/{name}")
    finally:
        for _ in range(50):  # the render's process has exited; the kernel drops it from the group at once
            try:
                folder.rmdir()
                break
            except OSError:
                time.sleep(0.1)
        if enabled is not None:
            with contextlib.suppress(OSError):
                _write(enabled / "cgroup.subtree_control", "-memory")


def test_render_in_a_small_cgroup_is_refused_before_rendering_or_fits(tmp_path):
    """In a 1 GiB cgroup: 4096×2160 is refused with one line naming the group, exit 2, nothing written
    (the machine itself has far more free); 160×90 renders, its plan line naming the same limit."""
    from forest.memory import meminfo_available

    free = meminfo_available()
    if free is not None and free < 2 * LIMIT:
        pytest.skip(f"the machine has {free / GiB:.1f} GiB available: a 1 GiB cgroup would not be the binding limit")
    cfg = tmp_path / "scene.toml"
    cfg.write_text(SCENE)
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")}
    env.pop("FOREST_MEMORY_GB", None)
    with memory_group(LIMIT) as group:
        named = f"(cgroup limit of 1.0 GiB on {group.path})"
        big = tmp_path / "big.exr"
        r = group.run("render", cfg, "-o", big, "--width", 4096, "--height", 2160, env=env)
        assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)  # not -9 / 137: killed by the kernel
        lines = [line for line in r.stderr.splitlines() if line.strip()]
        assert len(lines) == 1, r.stderr
        assert lines[0].startswith("forest: error: --width/--height: a 4096x2160 render needs about ")
        assert named in lines[0] and lines[0].endswith(" fits"), lines[0]
        assert not big.exists() and not big.with_suffix(".png").exists() and "rendered" not in r.stdout

        small = tmp_path / "small.exr"
        r = group.run("render", cfg, "-o", small, env=env)
        assert r.returncode == 0, (r.returncode, r.stdout, r.stderr)
        plan = [line for line in r.stderr.splitlines() if line.startswith("render: ")]
        assert len(plan) == 1 and "1 frame 160x90 at 4 spp" in plan[0] and named in plan[0], r.stderr
        assert small.stat().st_size > 0 and small.with_suffix(".png").stat().st_size > 0
        assert any(line.startswith("rendered 1 frame 160x90") for line in r.stdout.splitlines()), r.stdout
        peak = group.peak()
        assert peak is None or 0 < peak <= LIMIT
