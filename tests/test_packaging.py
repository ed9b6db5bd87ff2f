"""The built wheel works outside the checkout: the tree library and the example scenes ship with it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

from conftest import seed_library_cache

ROOT = Path(__file__).resolve().parents[1]


def run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=600, **kw)
    assert r.returncode == 0, (cmd, r.stdout[-2000:], r.stderr[-2000:])
    return r


def test_every_package_of_the_source_is_listed_for_the_wheel():
    """pyproject.toml lists packages explicitly (source folders map into the forest namespace)."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "forest").rglob("__init__.py")}
    assert found <= listed, sorted(found - listed)


def test_wheel_installs_into_a_fresh_venv_and_renders_the_packaged_demo(tmp_path):
    """``pip install forest-*.whl`` in a new virtual environment, then library list, examples and a render.

    The new environment gets forest from the wheel only; its third-party
    dependencies are taken from this environment's site-packages through a
    ``.pth`` line (installing mitsuba, usd-core … again would only test pip).
    Nothing of the checkout is on its path, and it runs in a folder outside it.
    """
    dist = tmp_path / "dist"
    run([sys.executable, "-m", "build", "--wheel", "--no-isolation", "--outdir", dist, ROOT], cwd=ROOT)
    (wheel,) = dist.glob("forest-*.whl")
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", "--without-pip", venv])
    py = venv / "bin" / "python"
    run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q", wheel])
    site = Path(run([py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (site / "forest_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["FOREST_LIBRARY"] = str(tmp_path / "user-library")
    # `library list` resolves every shipped species (reading and hashing each recipe from the wheel) and builds the
    # missing ones into the user library; building all ten took most of this test's time.  One of the demo's species
    # is left to be built from the wheel's recipe (the build from an installed package is what is proven here; the
    # generator's output per recipe is tests/test_library.py's); the others are copied from existing builds of the
    # same recipes (``seed_library_cache``).
    demo = tomllib.loads((ROOT / "configs" / "demo.toml").read_text())
    used = {s["model"] for s in demo.get("species", []) + demo.get("ground_cover", [])}
    shipped = tomllib.loads((ROOT / "library" / "manifest.toml").read_text())["species"]
    assert used and used <= set(shipped)
    to_build = "shrub" if "shrub" in used else min(used)
    seed_library_cache(tmp_path / "user-library", sorted(set(shipped) - {to_build}))
    cache = tmp_path / "user-library" / "cache"
    seeded = {p.name for p in cache.iterdir()} if cache.is_dir() else set()
    forest = venv / "bin" / "forest"

    where = run([py, "-c", "import forest; print(forest.__file__)"], cwd=work, env=env).stdout.strip()
    assert Path(where).is_relative_to(venv) and not Path(where).is_relative_to(ROOT)
    listed = json.loads(run([forest, "library", "list", "--json"], cwd=work, env=env).stdout)
    assert {"broadleaf", "conifer", "palm", "house"} <= {r["name"] for r in listed}
    # The shipped HDRI skies (library/skies) and their licence come with the wheel.
    skies = "from forest.hdri import SKIES, sky_path; print(all(sky_path(n).is_file() for n in SKIES))"
    assert run([py, "-c", skies], cwd=work, env=env).stdout.strip() == "True"
    assert (Path(where).parent / "library_files" / "skies" / "LICENSE-blender-studiolights.txt").is_file()
    config = run([forest, "examples", "copy", "demo", work / "demo"], cwd=work, env=env).stdout.strip()
    assert Path(config) == work / "demo" / "demo.toml" and (work / "demo" / "maps" / "demo_height.png").is_file()
    out = work / "out" / "demo.exr"
    # A tiny preview of the packaged demo, each species from one individual: the same code paths (the shipped
    # recipes built into the user library, the packaged maps read, forest_path rendering), a fraction of the time.
    small = ["--width", 64, "--height", 36, "--spp", 1]
    one_each = [a for i in range(3) for a in ("--set", f"species[{i}].individuals=1")]
    run([forest, "render", config, "--preview", *small, *one_each, "-o", out, "-q"], cwd=work, env=env)
    assert out.stat().st_size > 0 and out.with_suffix(".png").stat().st_size > 0
    # The user library got the build (the species left unbuilt, built from the wheel's recipe) and holds every
    # species the demo rendered; the installed package and the checkout were not written to.
    built = {p.name.rsplit("-", 1)[0] for p in cache.iterdir() if p.name not in seeded}
    assert to_build in built, (to_build, built)
    assert used <= {p.name.rsplit("-", 1)[0] for p in cache.iterdir()}
    assert not (Path(where).parent / "library_files" / "cache").exists()
