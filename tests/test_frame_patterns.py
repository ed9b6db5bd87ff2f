"""Frame specs and frame patterns read through fileseq: ``--frames 1-100x5``, ``-o f.%04d.exr`` / ``$F4`` / ``@@@@``."""

from __future__ import annotations

import fileseq
import pytest
from conftest import TINY_SCENE, run

from forest.cli import main
from forest.errors import ParameterError
from forest.frames import MAX_FRAMES, frame_path, parse_frames, still_path

SCENE = TINY_SCENE.replace(
    "[render]",
    "keys = [ { frame = 1, position = [0.0, 30.0, -60.0], target = [0.0, 0.0, 0.0] },\n"
    "         { frame = 9, position = [20.0, 25.0, -50.0], target = [0.0, 0.0, 0.0] } ]\n[render]",
)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    (d / "scene.toml").write_text(SCENE)
    with pytest.raises(SystemExit) as e:
        main(["scatter", str(d / "scene.toml"), "-o", str(d / "trees.npz"), "-q"])
    assert not e.value.code
    return d


@pytest.mark.parametrize(
    "spec, expected",
    [
        ("5", [5]),
        ("1-100x5", list(range(1, 101, 5))),
        ("1,5,9-12", [1, 5, 9, 10, 11, 12]),
        ("9-12,1,5", [1, 5, 9, 10, 11, 12]),
        ("1-10y3", sorted(set(range(1, 11)) - set(range(1, 11, 3)))),
        ("-3--1", [-3, -2, -1]),
        ("1-5,3-7", list(range(1, 8))),
    ],
)
def test_frame_specs_are_read_as_fileseq_frame_sets(spec, expected):
    assert parse_frames(spec) == expected
    assert parse_frames(spec) == sorted(int(f) for f in fileseq.FrameSet(spec))


@pytest.mark.parametrize(
    "spec, words",
    [
        ("9-1", "bad range '9-1'"),
        ("x", "cannot read 'x'"),
        ("1.5", "cannot read"),
        ("1-10#", "cannot read"),
        ("1,,2", "cannot read"),
        ("", "cannot read"),
        ("1-10x0", "cannot read"),
        (f"1-{MAX_FRAMES + 1}", f"more than {MAX_FRAMES} frames"),
        (f"1-{MAX_FRAMES},{MAX_FRAMES + 1}", f"more than {MAX_FRAMES} frames"),
    ],
)
def test_bad_frame_specs_are_refused_on_frames(spec, words):
    with pytest.raises(ParameterError) as e:
        parse_frames(spec)
    assert e.value.field == "frames" and words in e.value.message


@pytest.mark.parametrize(
    "pattern, width",
    [
        ("out/f_####.exr", 4),
        ("out/f.#.exr", 1),
        ("out/f.@@@@.exr", 4),
        ("out/f.@.exr", 1),
        ("out/f.%04d.exr", 4),
        ("out/f.%d.exr", 1),
        ("out/f.$F4.exr", 4),
        ("out/f.$F.exr", 1),
    ],
)
def test_each_pattern_token_becomes_the_padded_frame(pattern, width):
    token = next(t for t in ("####", "#", "@@@@", "@", "%04d", "%d", "$F4", "$F") if t in pattern)
    assert fileseq.getPaddingNum(token, fileseq.PAD_STYLE_HASH1) == width
    for frame in (7, 123):
        assert frame_path(pattern, frame) == pattern.replace(token, str(frame).zfill(width))


def test_a_pattern_without_a_token_keeps_its_old_names():
    assert frame_path("out/f.exr", 7) == "out/f_0007.exr"
    assert frame_path("out/f", 7) == "out/f_0007"
    assert frame_path("100%/f_####.exr", 7) == "100%/f_0007.exr"  # a folder is no pattern


@pytest.mark.parametrize(
    "pattern", ["f.%s.exr", "f.%4x.exr", "f.$T.exr", "f.${F4}.exr", "f.<UDIM>.exr", "f.##.%04d.exr"]
)
def test_unknown_or_repeated_tokens_are_refused_on_output(pattern):
    with pytest.raises(ParameterError) as e:
        frame_path(pattern, 1)
    assert e.value.field == "output" and pattern in e.value.message


@pytest.mark.parametrize(
    "pattern, frames, names",
    [
        ("f.%04d.exr", "2,6", ["f.0002", "f.0006"]),
        ("f.$F4.exr", "1-9x4", ["f.0001", "f.0005", "f.0009"]),
        ("f.@@@.exr", "3", ["f.003"]),
        ("f_####.exr", "1-2", ["f_0001", "f_0002"]),
    ],
)
def test_render_writes_one_file_per_frame_named_by_the_pattern(scene, tmp_path, pattern, frames, names):
    args = ["render", scene / "scene.toml", "--instances", scene / "trees.npz", "-q"]
    assert run([*args, "--frames", frames, "-o", tmp_path / pattern]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"{n}.{e}" for n in names for e in ("exr", "png"))


@pytest.mark.parametrize(
    "args, flag",
    [
        (["--frames", "1-3", "-o", "{d}/f.%s.exr"], "-o: "),
        (["--frames", "1-3", "-o", "{d}/f.$T.exr"], "-o: "),
        (["--frames", "1-3x0", "-o", "{d}/f.####.exr"], "--frames: "),
        (["--frames", "3-1", "-o", "{d}/f.%04d.exr"], "--frames: "),
    ],
)
def test_render_refuses_a_bad_pattern_or_spec_in_one_line(scene, tmp_path, capsys, args, flag):
    args = [a.format(d=tmp_path) for a in args]
    assert run(["render", scene / "scene.toml", "--instances", scene / "trees.npz", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"forest: error: {flag}") and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


def test_a_still_to_a_pattern_is_frame_1_named_by_it(scene, tmp_path):
    """As Nuke and Houdini render the current frame through the pattern: no literal %04d in a file name."""
    assert still_path("out/f.%04d.exr") == "out/f.0001.exr" and still_path("out/f.$F.exr") == "out/f.1.exr"
    assert still_path("out/f.exr") == "out/f.exr"  # no token: the name as given, no _0001
    args = ["render", scene / "scene.toml", "--instances", scene / "trees.npz", "-q"]
    assert run([*args, "-o", tmp_path / "f.%04d.exr"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.0001.exr", "f.0001.png"]
    import OpenImageIO as oiio

    spec = oiio.ImageInput.open(str(tmp_path / "f.0001.exr")).spec()
    assert spec.get_int_attribute("forest:frame") == 1
