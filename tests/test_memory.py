"""forest.memory: the room this process may still allocate, from /proc and the cgroup files of fake trees."""

from __future__ import annotations

from pathlib import Path

import pytest

from forest.memory import CgroupLimit, Room, available_bytes, cgroup_limits, memory_room

MiB = 1 << 20
GiB = 1 << 30
ROOT = Path(__file__).resolve().parents[1]

V2_MOUNT = "29 23 0:26 / /sys/fs/cgroup rw,nosuid,nodev,noexec,relatime shared:4 - cgroup2 cgroup2 rw,nsdelegate"
V1_MOUNT = "35 31 0:32 / /sys/fs/cgroup/memory rw,nosuid,nodev,noexec,relatime shared:9 - cgroup cgroup rw,memory"
V1_CPU = "32 31 0:29 / /sys/fs/cgroup/cpu rw,relatime shared:6 - cgroup cgroup rw,cpu"
PROC_MOUNT = "22 1 0:20 / /proc rw,nosuid,nodev,noexec,relatime shared:12 - proc proc rw"


def fake(
    tmp: Path, cgroup: str, mounts: list[str], files: dict[str, str | int], available: int | None = 8 * GiB
) -> tuple[Path, Path]:
    """A /proc (its meminfo, self/cgroup and self/mountinfo) and a root holding ``files``: (proc, root)."""
    proc, root = tmp / "proc", tmp / "root"
    (proc / "self").mkdir(parents=True)
    root.mkdir()
    if available is not None:
        (proc / "meminfo").write_text(
            f"MemTotal:       {32 * GiB // 1024} kB\nMemAvailable:   {available // 1024} kB\n"
        )
    (proc / "self" / "cgroup").write_text(cgroup)
    (proc / "self" / "mountinfo").write_text("".join(line + "\n" for line in mounts))
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{text}\n")
    return proc, root


def test_the_machine_alone_without_a_cgroup_limit(tmp_path):
    """v2 with "max" at every level (and none at the root): MemAvailable, and no cgroup named."""
    files = {
        "sys/fs/cgroup/user.slice/memory.max": "max",
        "sys/fs/cgroup/user.slice/memory.current": 5 * GiB,
        "sys/fs/cgroup/user.slice/job.scope/memory.max": "max",
        "sys/fs/cgroup/user.slice/job.scope/memory.current": GiB,
    }
    proc, root = fake(tmp_path, "0::/user.slice/job.scope\n", [PROC_MOUNT, V2_MOUNT], files)
    assert memory_room(proc, root) == Room(8 * GiB)
    assert cgroup_limits(proc, root) == []


def test_v2_own_group_limit_binds(tmp_path):
    """memory.max − memory.current of the process's own group (from /proc/self/cgroup), not the root's."""
    files = {
        "sys/fs/cgroup/memory.current": 20 * GiB,  # the root: no memory.max
        "sys/fs/cgroup/user.slice/memory.max": "max",
        "sys/fs/cgroup/user.slice/job.scope/memory.max": GiB,
        "sys/fs/cgroup/user.slice/job.scope/memory.current": 300 * MiB,
    }
    proc, root = fake(tmp_path, "0::/user.slice/job.scope\n", [V2_MOUNT], files)
    room = memory_room(proc, root)
    assert room == Room(724 * MiB, CgroupLimit("/user.slice/job.scope", 2, GiB, 300 * MiB))
    assert available_bytes(proc, root) == 724 * MiB


def test_a_parents_smaller_room_wins(tmp_path):
    """Nested groups: the parent's limit leaves less room than the child's own, so it binds."""
    files = {
        "sys/fs/cgroup/a/memory.max": 512 * MiB,
        "sys/fs/cgroup/a/memory.current": 400 * MiB,  # a sibling of b uses most of it
        "sys/fs/cgroup/a/b/memory.max": 2 * GiB,
        "sys/fs/cgroup/a/b/memory.current": 100 * MiB,
    }
    proc, root = fake(tmp_path, "0::/a/b\n", [V2_MOUNT], files)
    room = memory_room(proc, root)
    assert room is not None and room.bytes == 112 * MiB and room.cgroup is not None
    assert room.cgroup.path == "/a" and room.cgroup.limit == 512 * MiB
    assert [c.path for c in cgroup_limits(proc, root)] == ["/a/b", "/a"]


def test_the_machine_wins_when_it_has_less_room_than_the_limit(tmp_path):
    files = {"sys/fs/cgroup/job/memory.max": 16 * GiB, "sys/fs/cgroup/job/memory.current": GiB}
    proc, root = fake(tmp_path, "0::/job\n", [V2_MOUNT], files, available=3 * GiB)
    assert memory_room(proc, root) == Room(3 * GiB)


def test_the_inactive_page_cache_is_not_usage(tmp_path):
    """Written files fill the page cache up to the limit; its inactive part is reclaimed before a kill."""
    files = {
        "sys/fs/cgroup/job/memory.max": GiB,
        "sys/fs/cgroup/job/memory.current": 1000 * MiB,
        "sys/fs/cgroup/job/memory.stat": f"anon {200 * MiB}\nfile {800 * MiB}\ninactive_file {700 * MiB}",
    }
    proc, root = fake(tmp_path, "0::/job\n", [V2_MOUNT], files)
    assert available_bytes(proc, root) == GiB - 300 * MiB


def test_missing_files(tmp_path):
    """No memory.current: the limit alone; no memory.max: no limit at that level; no meminfo: the cgroups."""
    files = {"sys/fs/cgroup/a/memory.max": GiB, "sys/fs/cgroup/a/b/memory.current": 5 * GiB}
    proc, root = fake(tmp_path, "0::/a/b\n", [V2_MOUNT], files, available=None)
    assert memory_room(proc, root) == Room(GiB, CgroupLimit("/a", 2, GiB, 0))


def test_nothing_readable_is_none(tmp_path):
    proc, root = fake(tmp_path, "", [], {}, available=None)
    assert memory_room(proc, root) is None and available_bytes(proc, root) is None
    assert memory_room(tmp_path / "no-proc", tmp_path) is None


def test_v1_memory_hierarchy_found_through_mountinfo(tmp_path):
    """v1: the memory line of /proc/self/cgroup, the memory mount (not the cpu one), huge = no limit, and the
    hierarchical inactive file cache (total_inactive_file) left out of the usage."""
    unlimited = 9223372036854771712
    files = {
        "sys/fs/cgroup/memory/memory.limit_in_bytes": unlimited,
        "sys/fs/cgroup/memory/memory.usage_in_bytes": 20 * GiB,
        "sys/fs/cgroup/memory/slurm/memory.limit_in_bytes": unlimited,
        "sys/fs/cgroup/memory/slurm/memory.usage_in_bytes": 10 * GiB,
        "sys/fs/cgroup/memory/slurm/uid_1/job_7/memory.limit_in_bytes": GiB,
        "sys/fs/cgroup/memory/slurm/uid_1/job_7/memory.usage_in_bytes": 600 * MiB,
        "sys/fs/cgroup/memory/slurm/uid_1/job_7/memory.stat": f"inactive_file 0\ntotal_inactive_file {100 * MiB}",
        "sys/fs/cgroup/cpu/slurm/uid_1/job_7/memory.limit_in_bytes": MiB,  # not the memory hierarchy
    }
    cgroup = "5:cpu,cpuacct:/slurm/uid_1/job_7\n4:memory:/slurm/uid_1/job_7\n0::/\n"
    proc, root = fake(tmp_path, cgroup, [V1_CPU, V1_MOUNT], files)
    assert memory_room(proc, root) == Room(524 * MiB, CgroupLimit("/slurm/uid_1/job_7", 1, GiB, 500 * MiB))


def test_v1_container_mount_whose_root_is_the_group(tmp_path):
    """A container's memory mount shows its own group at the mount point (mountinfo's root field)."""
    mount = "40 31 0:32 /docker/abc /sys/fs/cgroup/memory ro,nosuid - cgroup cgroup rw,memory"
    files = {
        "sys/fs/cgroup/memory/memory.limit_in_bytes": 2 * GiB,
        "sys/fs/cgroup/memory/memory.usage_in_bytes": GiB,
    }
    proc, root = fake(tmp_path, "4:memory:/docker/abc\n", [mount], files)
    assert memory_room(proc, root) == Room(GiB, CgroupLimit("/docker/abc", 1, 2 * GiB, GiB))


def test_a_mount_elsewhere_with_an_escaped_name(tmp_path):
    """The hierarchy is where mountinfo says (octal escapes decoded), not assumed at /sys/fs/cgroup."""
    mount = r"29 23 0:26 / /run/my\040cgroups rw - cgroup2 none rw"
    files = {
        "run/my cgroups/job/memory.max": GiB,
        "run/my cgroups/job/memory.current": 0,
        "sys/fs/cgroup/job/memory.max": MiB,  # a decoy where the old reader looked
    }
    proc, root = fake(tmp_path, "0::/job\n", [mount], files)
    assert available_bytes(proc, root) == GiB


def test_preflight_names_the_binding_cgroup(tmp_path, monkeypatch):
    """The pre-flight error and the plan line name the cgroup limit when it is the one that binds."""
    from forest import memory, preflight
    from forest.errors import ForestError

    monkeypatch.delenv("FOREST_MEMORY_GB", raising=False)
    limit = CgroupLimit("/user.slice/user-1000.slice/run-r1.scope", 2, GiB, 100 * MiB)
    monkeypatch.setattr(memory, "memory_room", lambda: Room(limit.room, limit))
    est = preflight.render_estimate(4096, 2160, 16, 0, "scalar_rgb")
    with pytest.raises(ForestError) as e:
        preflight.check_render_memory(None, est, flags=True)
    message = str(e.value)
    assert message.startswith(
        f"--width/--height: a 4096x2160 render needs about {preflight.format_bytes(est.memory)}, 924.0 MiB available "
        "(cgroup limit of 1.0 GiB on /user.slice/user-1000.slice/run-r1.scope); "
    )
    assert message.endswith(" fits") and "\n" not in message
    assert preflight.available_memory() == limit.room
    small = preflight.render_estimate(64, 36, 1, 0, "scalar_rgb")
    room = preflight.memory_room()
    assert preflight.check_render_memory(None, small, available=room) == limit.room
    named = "of 924.0 MiB available (cgroup limit of 1.0 GiB on /user.slice/user-1000.slice/run-r1.scope), about"
    assert named in small.line(room)
    # The machine binding, or $FOREST_MEMORY_GB: no cgroup named.
    monkeypatch.setattr(memory, "memory_room", lambda: Room(924 * MiB))
    assert "cgroup" not in small.line(preflight.memory_room())
    monkeypatch.setenv("FOREST_MEMORY_GB", "8")
    assert preflight.memory_room() == Room(8 * GiB)


def test_memory_is_read_in_one_place():
    """MemAvailable and the cgroup files are read by forest.memory alone (forest/ and service/)."""
    from forest import memory
    from forest.render.path import geometry

    assert geometry.available_bytes is memory.available_bytes
    readers = []
    for folder in ("forest", "service"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text(encoding="utf-8")
            if any(s in text for s in ("meminfo", "memory.current", "usage_in_bytes")):
                readers.append(path.relative_to(ROOT).as_posix())
    assert readers == ["forest/memory.py"]


def test_a_mount_from_outside_the_namespace_reads_its_top(tmp_path):
    """A cgroup namespace whose mount's root is no ancestor of the process's group ("/.."): the mount point is
    read as the process's group, named as /proc/self/cgroup names it."""
    mount = "29 23 0:26 /.. /sys/fs/cgroup rw - cgroup2 cgroup2 rw"
    files = {"sys/fs/cgroup/memory.max": GiB, "sys/fs/cgroup/memory.current": GiB // 2}
    proc, root = fake(tmp_path, "0::/\n", [mount], files)
    assert memory_room(proc, root) == Room(GiB // 2, CgroupLimit("/", 2, GiB, GiB // 2))
