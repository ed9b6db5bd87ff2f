"""Tree library speed: generating every preset at every level of detail, and importing a large mesh.

Targets (from the library's issue): all presets at all levels ≤ 30 s; importing a
200 000-triangle mesh with its levels of detail and preview ≤ 20 s.  Several
individuals per species: building 4 individuals of every tree species, printed
with its ratio to building one (ideally 4: each individual costs what one does).

    .venv/bin/python bench/bench_library.py
"""

from __future__ import annotations

import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def big_tree_obj(folder: Path, triangles: int = 200_000) -> Path:
    """Write an OBJ + MTL tree of about ``triangles`` triangles: a trunk and a dense crown."""
    import trimesh

    n = int(np.sqrt(triangles / 4.0))  # a uv-sphere of count [n, n] has about 4·n² triangles
    crown = trimesh.creation.uv_sphere(radius=2.5, count=[n, n])
    crown.apply_scale([1.0, 0.8, 1.0])
    crown.apply_translation([0, 5.0, 0])
    trunk = trimesh.creation.cylinder(radius=0.25, height=4.0, sections=32)
    trunk.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    trunk.apply_translation([0, 2.0, 0])
    lines = ["mtllib big.mtl"]
    off = 0
    for name, mat, m in (("trunk", "bark", trunk), ("crown", "foliage", crown)):
        lines.append(f"o {name}")
        lines += [f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in m.vertices]
        lines.append(f"usemtl {mat}")
        lines += [f"f {a + 1 + off} {b + 1 + off} {c + 1 + off}" for a, b, c in m.faces]
        off += len(m.vertices)
    (folder / "big.mtl").write_text("newmtl bark\nKd 0.12 0.08 0.05\nnewmtl foliage\nKd 0.06 0.15 0.03\n")
    path = folder / "big.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


class Timer:
    """Wall-clock and process CPU seconds (all threads) of a block; the machine may be shared."""

    def __enter__(self):
        self.w, self.c = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall = time.perf_counter() - self.w
        self.cpu = time.process_time() - self.c

    def __str__(self):
        return f"{self.wall:6.2f} s wall, {self.cpu:6.2f} s CPU"


def main() -> None:
    from forest.library import open_library
    from forest.library.importer import add_species
    from forest.runtime import mitsuba

    mitsuba("scalar_rgb")  # import once, outside the timings
    import colour  # noqa: F401      # (colour-science is imported by image writing)

    tmp = Path(tempfile.mkdtemp(prefix="forest-bench-library-"))
    try:
        root = tmp / "lib"
        root.mkdir()
        shutil.copy(ROOT / "library/manifest.toml", root / "manifest.toml")
        shutil.copytree(ROOT / "library/presets", root / "presets")
        lib = open_library(root)
        import os

        print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
        # Several individuals per tree species, in a library of their own (a cold cache).
        from forest.library import individual, individuals

        root4 = tmp / "lib4"
        root4.mkdir()
        shutil.copy(ROOT / "library/manifest.toml", root4 / "manifest.toml")
        shutil.copytree(ROOT / "library/presets", root4 / "presets")
        lib4 = open_library(root4, presets=False)
        trees = [n for n in lib4.names() if lib4.recipe(n)[0].get("kind", "tree") == "tree"]
        with Timer() as t_one:
            for n in trees:
                individual(lib4, n, 0)
        with Timer() as t_more:
            for n in trees:
                individuals(lib4, n, 4)  # individual 0 is cached: builds 1, 2 and 3
        four = t_more.wall + t_one.wall
        print(f"build 1 individual of {len(trees)} tree species:   {t_one}")
        four_cpu = t_more.cpu + t_one.cpu
        print(
            f"build 4 individuals of {len(trees)} tree species:  {four:6.2f} s wall, {four_cpu:6.2f} s CPU   "
            f"(ratio to one individual: {four / t_one.wall:.2f} wall, {four_cpu / max(t_one.cpu, 1e-9):.2f} CPU; "
            "4 is linear)"
        )
        with Timer() as t_gen:
            species = lib.build(previews=False)
        with Timer() as t_prev:
            for sp in species:
                sp.preview  # noqa: B018 - renders when missing
        print(f"generate {len(species)} presets x 4 levels of detail: {t_gen}   (target <= 30 s)")
        for sp in species:
            print(f"    {sp.name:10s} " + "  ".join(f"{l.name} {l.triangles:>7,}" for l in sp.lods))
        print(f"render {len(species)} previews:                    {t_prev}")
        with Timer() as t_fresh:
            open_library(root).build()
        print(f"build again with a fresh cache (set-up re-run):   {t_fresh}")

        obj = big_tree_obj(tmp)
        with Timer() as t_imp:
            sp = add_species(lib, obj, "big")
        print(
            f"import a {sum(1 for line in obj.open() if line.startswith('f ')):,}-triangle OBJ with levels of detail "
            f"and preview: {t_imp}   (target <= 20 s)"
        )
        print("    " + "  ".join(f"{l.name} {l.triangles:>7,}" for l in sp.lods))
        print(f"load average at end: {os.getloadavg()[0]:.1f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
