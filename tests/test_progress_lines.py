"""Progress off a terminal: ``Progress: N%`` lines a render farm can read, the mode switch, the render's build steps."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from forest import progress
from forest.progress import ProgressLines, progress_bar, progress_mode

ROOT = Path(__file__).resolve().parents[1]
#: What a farm manager's log parser matches (Deadline's and OpenCue's progress handlers look for this).
FARM = re.compile(r"^Progress: (\d{1,3})%(?: (.*))?$")


class Clock:
    """A clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def parsed(text: str) -> list[tuple[int, str]]:
    out = []
    for line in text.splitlines():
        m = FARM.match(line)
        assert m, f"not a farm progress line: {line!r}"
        out.append((int(m.group(1)), m.group(2) or ""))
    return out


@pytest.fixture(autouse=True)
def no_mode_set(monkeypatch):
    """Each test starts with no --progress given and no FOREST_PROGRESS."""
    monkeypatch.setattr(progress, "_mode", None)
    monkeypatch.delenv(progress.ENV, raising=False)


def test_lines_print_whole_percent_steps_and_new_messages_at_most_once_an_interval():
    out, clock = io.StringIO(), Clock()
    lines = ProgressLines("render", out, interval=1.0, clock=clock)
    lines.update(0.0, "building scene")  # the first line at once
    lines.update(0.004, "building scene")  # under a whole percent: nothing
    clock.now = 0.5
    lines.update(0.3, "pass 1/8")  # moved, but the last line is too recent
    clock.now = 1.6
    lines.update(0.3, "pass 1/8")  # now it may be printed
    clock.now = 1.7
    lines.update(0.301, "pass 1/8")  # same percent, same message
    clock.now = 3.0
    lines.update(0.2, "pass 1/8")  # going back with nothing new to say is not printed
    lines.update(0.42, "pass 3/8")
    lines.finish()
    got = parsed(out.getvalue())
    assert [p for p, _ in got] == [0, 30, 42, 100]
    assert all(msg.startswith("render") for _, msg in got)
    assert "building scene" in got[0][1] and "pass 1/8" in got[1][1] and "pass 3/8" in got[2][1]
    lines.finish()  # the last line is printed once
    assert len(parsed(out.getvalue())) == 4


def test_a_stage_already_at_100_percent_gets_no_second_final_line():
    out = io.StringIO()
    lines = ProgressLines("scene", out, interval=0.0)
    lines.update(0.5, "maps")
    lines.update(1.0, "scene")
    lines.finish()
    assert [p for p, _ in parsed(out.getvalue())] == [50, 100]


def test_auto_is_a_bar_on_a_terminal_and_lines_elsewhere(monkeypatch):
    assert progress_mode(Terminal()) == "bar"
    assert progress_mode(io.StringIO()) == "lines"
    monkeypatch.setenv(progress.ENV, "none")
    assert progress_mode(Terminal()) == "none"
    monkeypatch.setenv(progress.ENV, "lines")
    assert progress_mode(Terminal()) == "lines"
    progress.set_mode("bar")  # --progress wins over the environment
    assert progress_mode(io.StringIO()) == "bar"
    progress.set_mode("auto")
    assert progress_mode(io.StringIO()) == "lines"
    with pytest.raises(ValueError):
        progress.set_mode("sometimes")


def test_progress_bar_in_lines_mode_ends_at_100_percent_and_quiet_prints_nothing(capsys):
    progress.set_mode("lines")
    with progress_bar("scatter") as bar:
        bar(0.0, "candidates")
    err = capsys.readouterr().err
    assert [p for p, _ in parsed(err)] == [0, 100]
    with progress_bar("scatter", quiet=True) as bar:
        bar(0.5, "species")
    progress.set_mode("none")
    with progress_bar("scatter") as bar:
        bar(0.5, "species")
    assert capsys.readouterr().err == ""


def test_a_failed_stage_does_not_claim_100_percent(capsys):
    progress.set_mode("lines")
    with pytest.raises(RuntimeError), progress_bar("render") as bar:
        bar(0.0, "building scene")
        raise RuntimeError("broken")
    assert [p for p, _ in parsed(capsys.readouterr().err)] == [0]


def test_the_cli_prints_lines_when_stderr_is_not_a_terminal(tmp_path, flat_scene):
    """``forest scatter`` run as a farm runs it (stderr to a log): lines by default, none with -q or --progress."""
    env = {k: v for k, v in os.environ.items() if k != progress.ENV}
    cmd = [sys.executable, "-m", "forest.cli"]
    cfg = flat_scene(count=50)
    r = subprocess.run([*cmd, "scatter", cfg, "-o", tmp_path / "a.npz"], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    got = parsed("\n".join(line for line in r.stderr.splitlines() if line.startswith("Progress:")))
    assert got and got[-1][0] == 100 and got[-1][1].startswith("scatter")
    assert [p for p, _ in got] == sorted(p for p, _ in got)
    for extra in (
        ["scatter", cfg, "-o", tmp_path / "b.npz", "-q"],
        ["--progress", "none", "scatter", cfg, "-o", tmp_path / "c.npz"],
    ):
        r = subprocess.run([*cmd, *map(str, extra)], capture_output=True, text=True, env=env)
        assert r.returncode == 0 and "Progress:" not in r.stderr, r.stderr


def test_the_scene_build_reports_its_steps_between_0_and_1(tmp_path):
    """forest_path's scene build says what it is doing, in order, before the first pass."""
    from test_render import trees
    from test_render_pipeline import scene_config

    from forest.render.render import frame_size, make_renderer
    from forest.runtime import find_llvm
    from forest.scene import load_scene

    from render_fixtures import BoxLibrary

    if find_llvm() is None:
        pytest.skip("llvm_ad_rgb needs LLVM 19")
    cfg = scene_config(tmp_path)
    scene = load_scene(
        cfg, trees([[-10.0, 0.0, 0.0], [10.0, 0.0, 0.0]], scale=5.0), library=BoxLibrary(tmp_path / "lib")
    )
    seen: list[tuple[float, str]] = []
    make_renderer(scene, "llvm_ad_rgb", frame_size(cfg, preview=False), progress=lambda f, m: seen.append((f, m)))
    fractions = [f for f, _ in seen]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0 and fractions == sorted(fractions)
    assert any(0.0 < f < 1.0 for f in fractions) and len({m for _, m in seen}) == len(seen)
    # The build inside the scene: prototypes, trees, then Mitsuba's one load_dict call, before and after.
    steps = [m for _, m in seen]
    at = {
        key: next(i for i, m in enumerate(steps) if m.startswith(key))
        for key in (
            "geometry: terrain",
            "geometry: 1/",
            "instances 2/2",
            "Mitsuba scene: loading",
            "Mitsuba scene loaded",
        )
    }
    assert list(at.values()) == sorted(at.values()), steps
    assert 0.25 < seen[at["instances 2/2"]][0] < seen[at["Mitsuba scene loaded"]][0] < 1.0


def test_render_and_wedge_take_progress_after_the_command(tmp_path, flat_scene, capsys, monkeypatch):
    """``forest render … --progress lines`` wins over ``forest --progress none``, and the lines show the scene build
    inside the render stage (trees written in blocks, Mitsuba's load before and after); ``--progress none`` after
    the command silences them."""
    from forest.cli import main
    from forest.render.path import geometry
    from forest.runtime import find_llvm

    if find_llvm() is None:
        pytest.skip("llvm_ad_rgb needs LLVM 19")
    monkeypatch.setattr(progress, "LINE_INTERVAL_S", 0.0)  # every step, not one a second
    monkeypatch.setattr(geometry, "REPORT_TREES", 10)
    cfg = flat_scene(
        "[camera]\nposition = [0.0, 40.0, -80.0]\ntarget = [0.0, 0.0, 0.0]\n"
        '[render]\nwidth = 16\nheight = 9\nspp = 1\nvariant = "llvm_ad_rgb"\n',
        count=40,
    )
    trees = tmp_path / "t.npz"
    with pytest.raises(SystemExit) as e:
        main(["scatter", str(cfg), "-o", str(trees), "-q"])
    assert not e.value.code
    capsys.readouterr()

    def run(*argv: str) -> list[tuple[int, str]]:
        with pytest.raises(SystemExit) as e:
            main(list(argv))
        err = capsys.readouterr().err
        assert not e.value.code, err
        return parsed("\n".join(line for line in err.splitlines() if line.startswith("Progress:")))

    got = run(
        "--progress",
        "none",
        "render",
        str(cfg),
        "--instances",
        str(trees),
        "-o",
        str(tmp_path / "a.exr"),
        "--progress",
        "lines",
    )
    build = [m for _, m in got if m.startswith("render: building scene: ")]
    placed = [m.split("instances ", 1)[1].split()[0] for m in build if "instances " in m]
    assert len(placed) >= 3 and placed[-1] == "40/40", build  # the trees, prototype by prototype
    assert any("Mitsuba scene: loading" in m for m in build) and any("Mitsuba scene loaded" in m for m in build)
    assert [p for p, _ in got] == sorted(p for p, _ in got) and got[-1][0] == 100
    out = tmp_path / "w.exr"
    wedge = ["wedge", str(cfg), "--instances", str(trees), "--wedge", "render.exposure=0", "-o", str(out)]
    assert run("--progress", "lines", *wedge, "--progress", "none") == []
    assert (tmp_path / "w_exposure_0.exr").is_file()
    with pytest.raises(SystemExit) as e:
        main(["render", str(cfg), "-o", str(tmp_path / "b.exr"), "--progress", "sometimes"])
    assert e.value.code == 2 and "--progress" in capsys.readouterr().err


def test_the_build_share_stays_inside_the_bar(monkeypatch):
    import forest.preflight as preflight
    from forest.render.frame import FrameSize
    from forest.render.render import build_share

    monkeypatch.setattr(preflight, "throughput", lambda _v: (1e-6, 1e-5, True))
    small, mid, large = FrameSize(64, 36, 4), FrameSize(640, 360, 16), FrameSize(3840, 2160, 256)
    shares = [build_share("llvm_ad_rgb", trees, mid, 1) for trees in (10, 1_000, 1_000_000)]
    assert shares == sorted(shares) and 0.05 < shares[0] < shares[-1] < 0.95  # more trees: a longer build
    assert build_share("llvm_ad_rgb", 1_000_000, large, 100) == 0.05  # the samples dwarf the build
    assert build_share("llvm_ad_rgb", 1_000_000, small, 1) == 0.95  # the build dwarfs the samples
