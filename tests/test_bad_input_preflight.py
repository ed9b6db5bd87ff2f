"""Pre-flight and one-line errors, piece by piece: output paths, atomic writes, captured stderr, decoders,
InstanceSets, species, environment maps, memory estimates, references, imports, and forest's own bugs."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import run_forest, write_png, write_scene

from forest.errors import ConfigError, ForestError, ParameterError

UNWRITABLE = Path("/sys/forest-test")


def _listing(folder: Path) -> list[str]:
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


# -- output paths -------------------------------------------------------------------------------


def test_output_file_accepts_missing_folders_and_creates_nothing(tmp_path):
    from forest.preflight import output_file, output_folder

    assert output_file(tmp_path / "a" / "b" / "frame.exr") == tmp_path / "a" / "b" / "frame.exr"
    assert output_folder(tmp_path / "c" / "lookdev") == tmp_path / "c" / "lookdev"
    assert _listing(tmp_path) == []


@pytest.mark.parametrize(
    "make, target, words",
    [
        (lambda d: (d / "frame.exr").mkdir(), "frame.exr", ["is a folder"]),
        (lambda d: (d / "afile").write_text("x"), "afile/sub/frame.exr", ["afile", "is a file, not a folder"]),
        (lambda d: None, str(UNWRITABLE / "frame.exr"), ["cannot write into /sys"]),
        (lambda d: None, "x" * 300 + ".exr", ["longer than"]),
    ],
)
def test_output_file_refusals_name_the_parameter(tmp_path, make, target, words):
    from forest.preflight import output_file

    make(tmp_path)
    before = _listing(tmp_path)
    with pytest.raises(ParameterError) as e:
        output_file(tmp_path / target)
    assert e.value.field == "output" and "\n" not in str(e.value)
    for w in words:
        assert w in e.value.message
    assert _listing(tmp_path) == before


def _unprivileged() -> list[str] | None:
    """A command prefix that runs as an ordinary user: none needed, ``setpriv`` to nobody as root, or None."""
    import shutil

    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    return [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"] if setpriv else None


def test_render_into_a_read_only_folder_is_one_line():
    """A real read-only folder (as an ordinary user: root writes anywhere) fails at once, leaving it empty."""
    import shutil
    import tempfile

    prefix = _unprivileged()
    if prefix is None:
        pytest.skip("running as root without setpriv")
    base = Path(tempfile.mkdtemp(prefix="forest-ro-"))
    try:
        base.chmod(0o755)
        cfg = write_scene(base, "[terrain]\nflat = {}\n[[species]]\nmodel = 'palm'\npercent = 5\n")
        cfg.chmod(0o644)
        ro = base / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        forest = [sys.executable, "-m", "forest.cli"]
        env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
        probe = subprocess.run(
            [*prefix, sys.executable, "-c", "import forest.cli"], capture_output=True, env=env, cwd=base
        )
        if probe.returncode != 0:
            # a checkout in a private folder (e.g. made by mktemp -d, mode 0700) is unreadable to the ordinary user;
            # tests/bad_inputs covers the unwritable output for root through a place no process can write into
            pytest.skip("the ordinary user cannot read this checkout")
        r = subprocess.run(
            [*prefix, *forest, "render", str(cfg), "-o", str(ro / "frame.exr")],
            capture_output=True,
            text=True,
            env=env,
            cwd=base,
        )
        assert r.returncode == 2, r.stderr
        assert r.stderr.strip() == f"forest: error: -o: {ro / 'frame.exr'}: cannot write into {ro}: permission denied"
        assert list(ro.iterdir()) == []
    finally:
        shutil.rmtree(base, ignore_errors=True)


def test_free_space_is_checked(tmp_path):
    import shutil

    from forest.preflight import check_free_space

    free = shutil.disk_usage(tmp_path).free
    check_free_space(tmp_path / "new" / "f.exr", 1024)
    with pytest.raises(ParameterError, match="free on its disk") as e:
        check_free_space(tmp_path / "new" / "f.exr", free * 2 + 2**40)
    assert e.value.field == "output"


def test_output_folder_refuses_a_file(tmp_path):
    from forest.preflight import output_folder, output_folder_argument

    (tmp_path / "out").write_text("x")
    with pytest.raises(ParameterError, match="not a folder"):
        output_folder(tmp_path / "out")
    with pytest.raises(ForestError, match="not a folder") as e:
        output_folder_argument(tmp_path / "out")
    assert not isinstance(e.value, ParameterError)


def test_atomic_path_turns_refusals_into_one_line(tmp_path):
    from forest.atomic import atomic_dir, atomic_path

    (tmp_path / "dir.exr").mkdir()
    with pytest.raises(ForestError, match="is a folder"), atomic_path(tmp_path / "dir.exr") as tmp:
        tmp.write_text("x")
    (tmp_path / "afile").write_text("x")
    with pytest.raises(ForestError, match="afile is a file, not a folder"), atomic_path(tmp_path / "afile/f.txt"):
        pass
    with pytest.raises(ForestError, match="not a folder"), atomic_dir(tmp_path / "afile"):
        pass
    # A full disk while writing names the output, not the temporary file, and leaves nothing behind.
    with pytest.raises(ForestError, match=r"out\.txt: cannot write") as e, atomic_path(tmp_path / "out.txt"):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp_path / ".out.tmp"))
    assert ".tmp" not in str(e.value)
    assert _listing(tmp_path) == ["afile", "dir.exr"]


# -- stderr of C libraries, decoders ------------------------------------------------------------


def test_captured_stderr_takes_what_c_libraries_print(capfd):
    from forest.runtime import captured_stderr

    with captured_stderr() as lines:
        os.write(2, b"libfoo error: something broke\n\n  \nlibfoo: and more\n")
    assert lines == ["libfoo error: something broke", "libfoo: and more"]
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


@pytest.mark.parametrize("cut", ["truncated", "garbage"])
def test_a_broken_png_is_one_error_and_no_libpng_noise(tmp_path, capfd, cut):
    from forest.images import read_image

    good = write_png(tmp_path / "good.png", np.random.default_rng(1).random((32, 32, 3))).read_bytes()
    bad = tmp_path / "bad.png"
    bad.write_bytes(good[: len(good) // 2] if cut == "truncated" else good[:40] + bytes(range(256)))
    capfd.readouterr()
    with pytest.raises(ForestError) as e:
        read_image(bad, what="colour map")
    assert str(e.value).startswith(f"{bad}: cannot read colour map: ") and "\n" not in str(e.value)
    assert capfd.readouterr().err == ""


def test_a_truncated_jpeg_is_refused_not_greyed(tmp_path):
    import OpenImageIO as oiio

    from forest.images import read_image

    p = tmp_path / "t.jpg"
    out = oiio.ImageOutput.create(str(p))
    out.open(str(p), oiio.ImageSpec(64, 64, 3, oiio.UINT8))
    out.write_image((np.random.default_rng(2).random((64, 64, 3)) * 255).astype(np.uint8))
    out.close()
    data = p.read_bytes()
    p.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(ForestError, match=r"Premature end of JPEG file$"):
        read_image(p)


# -- InstanceSets -------------------------------------------------------------------------------


def _inst(edit=None):
    from forest.instances import COLUMNS, InstanceSet

    n = 5
    cols = {k: np.zeros((n, *s), dtype=d) for k, (d, s) in COLUMNS.items()}
    cols["id"] = np.arange(10, 10 + n, dtype=np.uint64)
    cols["rotation"][:, 0] = 1.0
    cols["scale"][:] = 1.0
    cols["tint"][:] = 1.0
    if edit:
        edit(cols)
    return InstanceSet(**cols, species_names=["broadleaf"], extent=(0.0, 0.0, 1.0, 1.0))


@pytest.mark.parametrize(
    "column, edit, words",
    [
        ("position", lambda c: c["position"].__setitem__((2, 0), np.nan), ["'position'", "NaN", "tree id 12"]),
        ("normal", lambda c: c["normal"].__setitem__((4, 2), -np.inf), ["'normal'", "tree id 14"]),
        ("phase", lambda c: c["phase"].__setitem__(0, np.nan), ["'phase'", "tree id 10"]),
        ("scale", lambda c: c["scale"].__setitem__(1, -2.0), ["'scale'", "> 0", "tree id 11"]),
        ("rotation", lambda c: c["rotation"].__setitem__(3, 0.0), ["'rotation'", "tree id 13"]),
        ("species", lambda c: c["species"].__setitem__(0, 1), ["'species'", "1 species names"]),
        ("partition", lambda c: c["partition"].__setitem__(2, -1), ["'partition'", "tree id 12"]),
    ],
)
def test_instance_sets_are_checked_on_load(tmp_path, column, edit, words):
    from forest.instances import InstanceSet

    good = tmp_path / "good.npz"
    _inst().save(good)
    assert len(InstanceSet.load(good)) == 5
    bad = tmp_path / "bad.npz"
    _inst(edit).save(bad)
    with pytest.raises(ForestError) as e:
        InstanceSet.load(bad)
    assert str(e.value).startswith(f"{bad}: column {words[0]}")
    for w in words:
        assert w in str(e.value)


def test_a_non_npz_instance_file_is_one_line(tmp_path):
    from forest.instances import InstanceSet

    p = tmp_path / "t.npz"
    p.write_bytes(b"not a zip")
    with pytest.raises(ForestError, match=r"t\.npz: not a forest instance file"):
        InstanceSet.load(p)
    (tmp_path / "d.npz").mkdir()
    with pytest.raises(ForestError, match="is a folder"):
        InstanceSet.load(tmp_path / "d.npz")


# -- species ----------------------------------------------------------------------------------


class _Lib:
    def names(self):
        return ["broadleaf", "conifer", "palm"]


def _config(tmp_path, species: str):
    from forest.config import load_config

    return load_config(write_scene(tmp_path, f"[terrain]\nflat = {{}}\n{species}"))


def test_species_are_checked_against_the_library(tmp_path):
    from forest.preflight import check_species

    ok = '[[species]]\nmodel = "palm"\npercent = 50\n[[species]]\nmodel = "conifer@7"\npercent = 50\n'
    check_species(_config(tmp_path, ok), _Lib())
    bad = ok.replace("conifer@7", "conifr@7")
    with pytest.raises(ConfigError) as e:
        check_species(_config(tmp_path, bad), _Lib())
    assert e.value.field == "species[1].model" and "did you mean 'conifer'?" in str(e.value)
    mesh = '[[species]]\nmodel = "trees/oak.obj"\npercent = 10\n'
    with pytest.raises(ConfigError, match=r"species\[0\]\.model: mesh file not found: trees/oak\.obj"):
        check_species(_config(tmp_path, mesh), _Lib())
    (tmp_path / "trees").mkdir()
    (tmp_path / "trees" / "oak.obj").write_text("v 0 0 0\n")
    check_species(_config(tmp_path, mesh), _Lib())


def test_load_scene_checks_species_before_scattering(tmp_path, monkeypatch):
    from forest import scatter as scatter_module
    from forest.scene import load_scene

    def no_scatter(*a, **k):
        raise AssertionError("scattered before the species were checked")

    monkeypatch.setattr(scatter_module, "scatter", no_scatter)
    cfg = _config(tmp_path, '[[species]]\nmodel = "brodleaf"\npercent = 100\n')
    with pytest.raises(ConfigError, match="did you mean 'broadleaf'"):
        load_scene(cfg, library=_Lib())


# -- environment maps ---------------------------------------------------------------------------


def _exr(path: Path, pixels: np.ndarray) -> Path:
    import OpenImageIO as oiio

    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), oiio.ImageSpec(w, h, c, oiio.FLOAT))
    out.write_image(pixels.astype(np.float32))
    out.close()
    return path


@pytest.mark.parametrize(
    "name, pixels, words",
    [
        ("nan.exr", np.where(np.arange(3) == 1, np.nan, 1.0) * np.ones((4, 8, 3)), ["NaN"]),
        ("neg.exr", -np.ones((4, 8, 3)), ["negative"]),
        ("two.exr", np.ones((4, 8, 2)), ["Mitsuba cannot read it", "channel count (2)"]),
    ],
)
def test_environment_maps_fail_naming_the_field(tmp_path, name, pixels, words):
    from forest.config import load_config
    from forest.render.scene import check_render_inputs, emitter_dicts

    _exr(tmp_path / name, pixels)
    cfg = load_config(
        write_scene(
            tmp_path,
            f'[terrain]\nflat = {{}}\n[[species]]\nmodel = "palm"\npercent = 5\n'
            f'[lights]\nsky = {{ envmap = "{name}" }}\n',
        )
    )
    for check in (check_render_inputs, lambda c: emitter_dicts(c, "scalar_rgb")):
        with pytest.raises(ConfigError) as e:
            check(cfg)
        assert e.value.field == "lights.sky.envmap" and name in str(e.value) and "\n" not in str(e.value)
        for w in words:
            assert w in str(e.value)


# -- memory and time ----------------------------------------------------------------------------


def test_render_memory_grows_with_pixels_trees_and_jit():
    from forest.preflight import render_memory

    base = render_memory(640, 360, 16, 1000, "scalar_rgb")
    assert render_memory(1280, 720, 16, 1000, "scalar_rgb") > base
    assert render_memory(640, 360, 16, 100_000, "scalar_rgb") > base
    assert render_memory(640, 360, 16, 1000, "llvm_ad_rgb") > base
    # 16384² in scalar_rgb needs tens of GiB: the film, beauty accumulators and output layers per pixel.
    assert render_memory(16384, 16384, 64, 10_000, "scalar_rgb") > 40 * 2**30


def test_the_largest_fitting_image_fits_and_the_next_does_not():
    from forest.preflight import largest_fitting, render_memory

    def need(w, h):
        return render_memory(w, h, 64, 10_000, "scalar_rgb")

    budget = 8 * 2**30
    w, h = largest_fitting(16384, 16384, budget, need)
    assert w == h and w % 16 == 0 and need(w, h) <= budget < need(w + 16, h + 16)
    w, h = largest_fitting(1920, 1080, budget, need)
    assert abs(w / h - 16 / 9) < 0.01
    assert largest_fitting(1920, 1080, 10, need) is None


def test_a_render_too_big_for_the_machine_names_the_size_and_what_fits(tmp_path, monkeypatch):
    from forest.preflight import check_render_memory, render_estimate

    cfg = _config(tmp_path, '[[species]]\nmodel = "palm"\npercent = 5\n[render]\nwidth = 16384\nheight = 16384\n')
    est = render_estimate(16384, 16384, 64, 0, "scalar_rgb")
    monkeypatch.setenv("FOREST_MEMORY_GB", "8")
    with pytest.raises(ConfigError) as e:
        check_render_memory(cfg, est)
    assert e.value.field == "render.width/render.height" and "8.0 GiB available" in str(e.value)
    assert "fits" in str(e.value)
    with pytest.raises(ForestError, match=r"^--width/--height: a 16384x16384 render"):
        check_render_memory(cfg, est, flags=True)
    small = render_estimate(64, 36, 4, 10, "scalar_rgb")
    assert check_render_memory(cfg, small) == 8 * 2**30
    monkeypatch.setenv("FOREST_MEMORY_GB", "-1")
    with pytest.raises(ForestError, match="FOREST_MEMORY_GB"):
        check_render_memory(cfg, small)


def test_available_memory_reads_the_machine(monkeypatch):
    from forest.preflight import available_memory

    monkeypatch.delenv("FOREST_MEMORY_GB", raising=False)
    room = available_memory()
    if Path("/proc/meminfo").is_file():
        total = int(next(li for li in open("/proc/meminfo") if li.startswith("MemTotal:")).split()[1]) * 1024
        assert room is not None and 0 < room <= total


def test_time_estimates_use_this_machines_last_render(tmp_path, monkeypatch):
    from forest import preflight

    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))
    before = preflight.render_estimate(640, 360, 16, 1000, "scalar_rgb")
    assert not before.measured
    preflight.record_render("scalar_rgb", samples=640 * 360 * 16, trees=1000, render_seconds=36.864, load_seconds=1)
    after = preflight.render_estimate(640, 360, 16, 1000, "scalar_rgb")
    assert after.measured and after.seconds == pytest.approx(preflight.SECONDS_FIXED["scalar"] + 36.864 + 1.0)
    assert "about" in after.line(8 * 2**30) and "8.0 GiB available" in after.line(8 * 2**30)


# -- references, imports ------------------------------------------------------------------------


def test_a_reference_needs_a_useful_size(tmp_path):
    from forest.lookdev.reference import load_reference, min_side

    assert min_side(96, 54) == 14 and min_side(16, 12) == 8
    tiny = write_png(tmp_path / "tiny.png", np.full((1, 1, 3), 0.5))
    with pytest.raises(ForestError, match=r"tiny\.png: reference is 1x1 pixels; the fit at 96x54 needs at least 14"):
        load_reference(tiny, 96, 54)
    ok = write_png(tmp_path / "ok.png", np.full((14, 25, 3), 0.5))
    assert load_reference(ok, 96, 54).rgb.shape == (54, 96, 3)


def test_a_failed_import_leaves_no_folder_behind(tmp_path):
    from forest.library import open_library
    from forest.library.importer import add_species

    flat = tmp_path / "flat.obj"
    flat.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 3\n")
    lib = open_library(tmp_path / "newlib")
    with pytest.raises(ForestError, match=r"flat\.obj: mesh has no surface area"):
        add_species(lib, flat, "flat")
    assert not (tmp_path / "newlib").exists()
    (tmp_path / "lib2").mkdir()
    with pytest.raises(ForestError):
        add_species(open_library(tmp_path / "lib2"), flat, "flat")
    assert _listing(tmp_path / "lib2") == []


# -- forest's own bugs, render plan -------------------------------------------------------------


def test_a_bug_is_one_line_with_the_traceback_saved(tmp_path):
    code = (
        "import forest.preflight as p\n"
        "p.output_file = lambda *a, **k: 1 / 0\n"
        "from forest.cli import main\n"
        "main(['schema', '-o', 'schema.json'])\n"
    )
    env = {**os.environ, "XDG_STATE_HOME": str(tmp_path / "state")}
    env.pop("FOREST_DEBUG", None)
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 1 and len(lines) == 1, r.stderr
    assert "internal error (a bug in forest, not in your input): ZeroDivisionError" in lines[0]
    saved = Path(lines[0].rsplit("the traceback is in ", 1)[1])
    assert saved.parent == tmp_path / "state" / "forest" / "tracebacks"
    text = saved.read_text()
    assert "Traceback" in text and "ZeroDivisionError" in text and "forest schema -o schema.json" in text
    assert not (tmp_path / "schema.json").exists()
    r = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env={**env, "FOREST_DEBUG": "1"}, capture_output=True, text=True
    )
    assert r.returncode == 1 and "Traceback" in r.stderr


def test_render_says_what_it_will_do_before_it_starts(tmp_path):
    cfg = write_scene(
        tmp_path,
        """
        seed = 3
        [terrain]
        flat = { size = 60.0 }
        [scatter]
        count = 12
        clumping = { strength = 0.0, clearings = 0.0 }  # every candidate stays: the count is known
        [[species]]
        model = "fern"
        percent = 100
        [camera]
        position = [0.0, 20.0, -50.0]
        target = [0.0, 0.0, 0.0]
        [render]
        width = 32
        height = 18
        spp = 2
        """,
    )
    env_state = tmp_path / "state"
    r = subprocess.run(
        [sys.executable, "-m", "forest.cli", "render", str(cfg), "-o", str(tmp_path / "f.exr")],
        capture_output=True,
        text=True,
        env={**os.environ, "XDG_STATE_HOME": str(env_state)},
    )
    assert r.returncode == 0, r.stderr
    plan, variant = r.stderr.strip().splitlines()[:2]
    assert plan.startswith("render: 1 frame 32x18 at 2 spp, 12 trees: about ") and "available" in plan
    assert variant.startswith("variant: ")
    assert (env_state / "forest" / "throughput.json").is_file()


def test_option_type_errors_are_one_line(tmp_path):
    r = run_forest("library", "preview", "shrub", "--size", "abc")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--size" in r.stderr and "╭" not in r.stderr


def test_a_scene_may_draw_on_at_most_256_tree_variants(tmp_path):
    """Seeded species and individuals are generated on first use (seconds and megabytes each): 10 000 of them ran
    for hours.  The count is checked before anything is built, naming the species that crosses the limit."""
    from forest.preflight import MAX_TREE_VARIANTS, check_species

    many = "".join(f'[[species]]\nmodel = "conifer@{i}"\npercent = 1\n' for i in range(70))  # 4 individuals each
    with pytest.raises(ConfigError) as e:
        check_species(_config(tmp_path, many), _Lib())
    assert e.value.field == "species[64].model"  # the 65th: 260 variants
    assert "260 tree variants" in str(e.value) and f"at most {MAX_TREE_VARIANTS}" in str(e.value)
    few = "".join(f'[[species]]\nmodel = "conifer@{i}"\npercent = 1\nindividuals = 1\n' for i in range(70))
    check_species(_config(tmp_path, few), _Lib())  # 70 variants: fine


def test_the_largest_fitting_image_is_found_where_memory_is_not_monotonic_in_size():
    """Just below the edge a smaller image can need a little more memory than a larger one (more samples per
    pass); the bisection's width rounded to 16 may then not fit, and a smaller one is offered instead of none
    (seen in a 1 GiB cgroup: "even a small image does not fit" at 970.8 MiB where 976x515 fit at 971.3)."""
    from forest.preflight import largest_fitting

    def need(w: int, h: int) -> int:
        return w * h + (10**6 if 960 < w <= 976 else 0)

    budget = 980 * 551
    assert largest_fitting(1920, 1080, budget, need) == (960, 540)
    assert need(960, 540) <= budget < need(976, 549)
