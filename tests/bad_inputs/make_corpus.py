"""Build the bad-input corpus: one folder per user mistake, each with the files it needs and ``case.json``.

Every case is something a new user does wrong — a misspelled species, a NaN in
an environment map, an output path into a read-only place, a truncated PNG, a
16384×16384 render on a small machine, ``--spp 0`` … — and says which command
line shows it (run inside the case's folder) and which words the one line of
the error must contain (the file or the field at fault).
``tests/test_bad_input_corpus.py`` runs every case and asserts: exit status 2,
exactly one line on stderr that starts ``forest: error:`` and names the file or
field, no traceback (on screen or saved as a bug), nothing written or changed
in the case's folder, and an answer within the time limit.

    python tests/bad_inputs/make_corpus.py OUT_DIR     # writes OUT_DIR/<case>/…

The files are made here (numpy + OpenImageIO), deterministically, so the
corpus is code: a new mistake is a new :class:`Case` in :func:`cases`.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: A place no process can write into, root included (sysfs refuses new files).
UNWRITABLE = "/sys/forest-corpus"

#: Memory budget (GiB) stated for every case, so that the memory cases do not depend on the machine.
MEMORY_GB = "8"


@dataclass
class Case:
    """One mistake: the files of its folder, the command line, the words its error line must contain."""

    name: str
    kind: str  # the class of mistake (output, input, species, value, memory, option, library, reference)
    argv: list[str]
    expect: list[str]
    files: dict[str, object] = field(default_factory=dict)  # relative path → content (see :func:`_write`)
    env: dict[str, str] = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------
# Files
# ---------------------------------------------------------------------------------------------


def _oiio_write(path: Path, pixels: np.ndarray, fmt: str) -> None:
    import OpenImageIO as oiio

    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    h, w, c = pixels.shape
    out = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(w, h, c, {"uint8": oiio.UINT8, "float": oiio.FLOAT, "half": oiio.HALF}[fmt])
    if path.suffix == ".exr":
        spec.attribute("DateTime", "")
    if not out.open(str(path), spec):
        raise RuntimeError(f"cannot write {path}: {out.geterror()}")
    out.write_image(np.ascontiguousarray(pixels))
    out.close()


def _grey(h: int = 16, w: int = 16, value: float = 0.5) -> np.ndarray:
    return np.full((h, w, 3), value, dtype=np.float32)


def _noise(h: int, w: int, seed: int = 1) -> np.ndarray:
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, 0xC0FFEE])))
    return (0.2 + 0.6 * rng.random((h, w, 3))).astype(np.float32)


def _png_bytes(pixels: np.ndarray, tmp: Path) -> bytes:
    p = tmp / "_tmp.png"
    _oiio_write(p, np.round(np.clip(pixels, 0, 1) * 255).astype(np.uint8), "uint8")
    data = p.read_bytes()
    p.unlink()
    return data


def _encoded(fn: Callable[[Path], None], suffix: str, tmp: Path) -> bytes:
    p = tmp / f"_tmp{suffix}"
    fn(p)
    data = p.read_bytes()
    p.unlink()
    return data


def _huge_png(width: int, height: int, rows: int = 4) -> bytes:
    """A few hundred bytes of PNG whose header declares ``width``×``height`` RGBA (only ``rows`` rows follow).

    A small upload that decodes to gigabytes: it must be refused from its header, before any decode.
    """
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    z = zlib.compressobj(9)
    idat = b"".join(z.compress(b"\0" * (1 + 4 * width)) for _ in range(rows)) + z.flush()
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


#: A binary PLY whose header claims two billion vertices, followed by 64 bytes.
HUGE_PLY = (
    b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\nproperty float y\n"
    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n" + b"\0" * 64
)


def _obj(vertices, faces) -> str:
    lines = [f"v {x} {y} {z}" for x, y, z in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    return "\n".join(lines) + "\n"


def _instances(tmp: Path, species=("broadleaf",), edit: Callable[[dict], None] | None = None) -> bytes:
    """A small valid InstanceSet (.npz bytes), optionally with its columns edited."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    from forest.instances import COLUMNS, InstanceSet

    n = 8
    cols = {k: np.zeros((n, *s), dtype=d) for k, (d, s) in COLUMNS.items()}
    cols["id"] = np.arange(n, dtype=np.uint64)
    cols["position"][:, 0] = np.linspace(-20, 20, n)
    cols["rotation"][:, 0] = 1.0
    cols["scale"][:] = 1.0
    cols["tint"][:] = 1.0
    cols["normal"][:, 1] = 1.0
    if edit is not None:
        edit(cols)
    inst = InstanceSet(**cols, species_names=list(species), extent=(-50.0, -50.0, 50.0, 50.0), seed=3)
    p = tmp / "_tmp.npz"
    inst.save(p)
    data = p.read_bytes()
    p.unlink()
    return data


# ---------------------------------------------------------------------------------------------
# Scenes
# ---------------------------------------------------------------------------------------------

SPECIES = '[[species]]\nmodel = "broadleaf"\npercent = 100\n'


def scene(extra: str = "", *, species: str = SPECIES, terrain: str = "flat = { size = 100.0 }") -> str:
    """A tiny valid scene (100 m flat terrain, 40 candidates, 48×27 pixels) plus ``extra`` TOML."""
    return (
        f"seed = 3\n[terrain]\n{terrain}\n[scatter]\ncount = 40\n{species}"
        "[camera]\nposition = [0.0, 30.0, -80.0]\ntarget = [0.0, 0.0, 0.0]\n"
        f"[render]\nwidth = 48\nheight = 27\nspp = 2\n{extra}"
    )


def with_sky(sky: str) -> str:
    return scene(f"[lights]\nsky = {{ {sky} }}\n")


RENDER = ["render", "scene.toml", "-o", "out/frame.exr"]
SCATTER = ["scatter", "scene.toml", "-o", "out/trees.npz"]
MATCH = ["match", "scene.toml", "--reference", "ref.png", "-o", "lookdev", "--iterations", "2"]


def cases(tmp: Path) -> list[Case]:
    """Every case of the corpus (``tmp``: a scratch folder for encoding files)."""
    nan_map = _grey(8, 16)
    nan_map[2:4] = np.nan
    neg_map = _grey(8, 16)
    neg_map[0, 0] = -2.0
    inf_map = _grey(8, 8)
    inf_map[1, 1] = np.inf

    good_png = _png_bytes(_noise(32, 32), tmp)
    exr_nan = _encoded(lambda p: _oiio_write(p, nan_map, "float"), ".exr", tmp)
    exr_neg = _encoded(lambda p: _oiio_write(p, neg_map, "float"), ".exr", tmp)
    exr_inf = _encoded(lambda p: _oiio_write(p, inf_map, "float"), ".exr", tmp)
    exr_two = _encoded(lambda p: _oiio_write(p, np.ones((8, 16, 2), np.float32), "float"), ".exr", tmp)
    exr_ok = _encoded(lambda p: _oiio_write(p, _grey(8, 16), "half"), ".exr", tmp)
    tif_ok = _encoded(lambda p: _oiio_write(p, _grey(8, 16), "float"), ".tif", tmp)
    jpg_ok = _encoded(lambda p: _oiio_write(p, np.round(_noise(64, 64) * 255).astype(np.uint8), "uint8"), ".jpg", tmp)
    ref_png = _png_bytes(_noise(54, 96, 2), tmp)
    ref_tiny = _png_bytes(_noise(1, 1, 3), tmp)
    ref_small = _png_bytes(_noise(6, 10, 4), tmp)
    mask_square = _png_bytes(_grey(40, 40, 1.0), tmp)
    trunc_png = good_png[: len(good_png) // 2]
    garbage_png = good_png[:40] + bytes(range(256)) * 2
    trunc_jpg = jpg_ok[: len(jpg_ok) * 2 // 3]
    trunc_exr = exr_ok[: len(exr_ok) // 2]
    trunc_tif = tif_ok[: len(tif_ok) // 2]
    inst_ok = _instances(tmp)

    def edit_nan_position(c):
        c["position"][3, 1] = np.nan

    def edit_zero_scale(c):
        c["scale"][5] = 0.0

    def edit_species_index(c):
        c["species"][2] = 7

    def edit_inf_tint(c):
        c["tint"][1, 0] = np.inf

    def edit_zero_rotation(c):
        c["rotation"][4] = 0.0

    def edit_partition_index(c):
        c["partition"][0] = 3

    flat_quad = _obj([(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)], [(0, 1, 2), (1, 2, 3)])
    nan_obj = _obj([(0, 0, 0), (1, 0, 0), ("nan", 0, 1)], [(0, 1, 2)])
    huge_obj = _obj([(0, 0, 0), (1e308, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    tri_obj = _obj([(0, 0, 0), (1, 0, 0), (0, 2, 0)], [(0, 1, 2)])
    deep = "seed = " + "[" * 2000 + "]" * 2000 + "\n"
    big = scene() + "# " + "x" * 1100 + "\n"
    big = big * 1000
    long_name = "f" * 300 + ".exr"

    L = Case
    out: list[Case] = [
        # -- output paths: refused before any work ------------------------------------------------
        L(
            "render_out_unwritable",
            "output",
            ["render", "scene.toml", "-o", f"{UNWRITABLE}/frame.exr"],
            ["-o", "/sys", "cannot write"],
            {"scene.toml": scene()},
        ),
        L(
            "render_out_parent_is_file",
            "output",
            ["render", "scene.toml", "-o", "afile/frame.exr"],
            ["-o", "afile", "is a file"],
            {"scene.toml": scene(), "afile": "x"},
        ),
        L(
            "render_out_is_folder",
            "output",
            ["render", "scene.toml", "-o", "frame.exr"],
            ["-o", "frame.exr", "is a folder"],
            {"scene.toml": scene(), "frame.exr/keep": "x"},
        ),
        L(
            "render_png_beside_is_folder",
            "output",
            ["render", "scene.toml", "-o", "frame.exr"],
            ["-o", "frame.png", "is a folder"],
            {"scene.toml": scene(), "frame.png/keep": "x"},
        ),
        L(
            "render_frame_is_folder",
            "output",
            ["render", "scene.toml", "-o", "seq/f_####.exr", "--frames", "1-3"],
            ["-o", "f_0002.exr", "is a folder"],
            {"scene.toml": scene(), "seq/f_0002.exr/keep": "x"},
        ),
        L(
            "match_out_folder_holds_the_scene",
            "output",
            ["match", "scene.toml", "--reference", "ref.png", "-o", ".", "--iterations", "2"],
            ["-o", "scene.toml", "is an input"],
            {"scene.toml": scene(), "ref.png": ref_png},
        ),
        L(
            "match_out_folder_holds_the_colour_map",
            "output",
            ["match", "scene.toml", "--reference", "ref.png", "-o", "maps", "--iterations", "2"],
            ["-o", "colour_map.exr", "is an input"],
            {
                "scene.toml": scene('[maps]\ncolour = "maps/colour_map.exr"\n'),
                "maps/colour_map.exr": exr_ok,
                "ref.png": ref_png,
            },
        ),
        L(
            "render_png_beside_is_the_colour_map",
            "output",
            ["render", "scene.toml", "-o", "colour.exr"],
            ["-o", "colour.png", "is an input"],
            {"scene.toml": scene('[maps]\ncolour = "colour.png"\n'), "colour.png": good_png},
        ),
        L(
            "export_rib_out_is_a_file_before_scatter",
            "output",
            ["export", "rib", "scene.toml", "-o", "afile"],
            ["-o", "afile", "not a folder"],
            {"scene.toml": scene(), "afile": "x"},
        ),
        L(
            "render_out_wrong_suffix",
            "output",
            ["render", "scene.toml", "-o", "frame.jpg"],
            ["-o", "frame.jpg", ".exr"],
            {"scene.toml": scene()},
        ),
        L(
            "render_out_name_too_long",
            "output",
            ["render", "scene.toml", "-o", long_name],
            ["-o", "longer than"],
            {"scene.toml": scene()},
        ),
        L(
            "render_out_unwritable_with_instances",
            "output",
            ["render", "scene.toml", "--instances", "trees.npz", "-o", f"{UNWRITABLE}/frame.exr"],
            ["-o", "/sys", "cannot write"],
            {"scene.toml": scene(), "trees.npz": inst_ok},
        ),
        L(
            "scatter_out_unwritable",
            "output",
            ["scatter", "scene.toml", "-o", f"{UNWRITABLE}/trees.npz"],
            ["-o", "/sys", "cannot write"],
            {"scene.toml": scene()},
        ),
        L(
            "scatter_out_parent_is_file",
            "output",
            ["scatter", "scene.toml", "-o", "afile/sub/trees.npz"],
            ["-o", "afile", "is a file"],
            {"scene.toml": scene(), "afile": "x"},
        ),
        L(
            "scatter_out_is_folder",
            "output",
            ["scatter", "scene.toml", "-o", "trees.npz"],
            ["-o", "trees.npz", "is a folder"],
            {"scene.toml": scene(), "trees.npz/keep": "x"},
        ),
        L(
            "scatter_out_wrong_suffix",
            "output",
            ["scatter", "scene.toml", "-o", "trees.csv"],
            ["-o", "trees.csv", ".npz"],
            {"scene.toml": scene()},
        ),
        L(
            "match_out_is_file",
            "output",
            ["match", "scene.toml", "--reference", "ref.png", "-o", "lookdev"],
            ["-o", "lookdev", "not a folder"],
            {"scene.toml": scene(), "ref.png": ref_png, "lookdev": "x"},
        ),
        L(
            "match_out_unwritable",
            "output",
            ["match", "scene.toml", "--reference", "ref.png", "-o", f"{UNWRITABLE}/lookdev"],
            ["-o", "/sys", "cannot write"],
            {"scene.toml": scene(), "ref.png": ref_png},
        ),
        L(
            "schema_out_is_folder",
            "output",
            ["schema", "-o", "schema.json"],
            ["-o", "schema.json", "is a folder"],
            {"schema.json/keep": "x"},
        ),
        L(
            "schema_out_unwritable",
            "output",
            ["schema", "-o", f"{UNWRITABLE}/schema.json"],
            ["-o", "/sys", "cannot write"],
        ),
        L(
            "preview_out_unwritable",
            "output",
            ["library", "preview", "shrub", "-o", f"{UNWRITABLE}/p.png"],
            ["-o", "/sys", "cannot write"],
        ),
        L(
            "examples_copy_into_file",
            "output",
            ["examples", "copy", "demo", "afile"],
            ["afile", "not a folder"],
            {"afile": "x"},
        ),
        # -- input files: readable, decodable, finite ------------------------------------------------
        L(
            "envmap_nan",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.exr", "NaN"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": exr_nan},
        ),
        L(
            "envmap_negative",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.exr", "negative"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": exr_neg},
        ),
        L(
            "envmap_truncated",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.exr", "cannot read"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": trunc_exr},
        ),
        L(
            "envmap_garbage",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.exr"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": b"v/1\x01\x02\x00\x00\x00" + b"junk" * 20},
        ),
        L(
            "envmap_two_channels",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.exr", "Mitsuba cannot read"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": exr_two},
        ),
        L(
            "envmap_tiff",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.tif", "Mitsuba reads"],
            {"scene.toml": with_sky('envmap = "sky.tif"'), "sky.tif": tif_ok},
        ),
        L(
            "envmap_empty",
            "input",
            RENDER,
            ["lights.sky.envmap", "sky.exr", "empty"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": b""},
        ),
        L(
            "envmap_missing",
            "input",
            RENDER,
            ["lights.sky.envmap", "not found"],
            {"scene.toml": with_sky('envmap = "sky.exr"')},
        ),
        L(
            "terrain_texture_inf",
            "input",
            RENDER,
            ["render.terrain_texture", "ground.exr", "infinite"],
            {"scene.toml": scene('terrain_texture = "ground.exr"\n'), "ground.exr": exr_inf},
        ),
        L(
            "colour_map_garbage_png",
            "input",
            SCATTER,
            ["maps.colour", "colour.png", "cannot read"],
            {"scene.toml": scene('[maps]\ncolour = "colour.png"\n'), "colour.png": garbage_png},
        ),
        L(
            "colour_map_truncated_png",
            "input",
            RENDER,
            ["maps.colour", "colour.png", "cannot read"],
            {"scene.toml": scene('[maps]\ncolour = "colour.png"\n'), "colour.png": trunc_png},
        ),
        L(
            "density_map_truncated_jpg",
            "input",
            SCATTER,
            ["maps.density", "density.jpg"],
            {"scene.toml": scene('[maps]\ndensity = "density.jpg"\n'), "density.jpg": trunc_jpg},
        ),
        L(
            "presence_map_truncated_tif",
            "input",
            SCATTER,
            ["maps.presence", "presence.tif"],
            {"scene.toml": scene('[maps]\npresence = "presence.tif"\n'), "presence.tif": trunc_tif},
        ),
        L(
            "heightmap_truncated_exr",
            "input",
            SCATTER,
            ["terrain.heightmap", "height.exr"],
            {"scene.toml": scene(terrain='heightmap = "height.exr"\nsize = [100.0, 100.0]'), "height.exr": trunc_exr},
        ),
        L(
            "heightmap_is_text",
            "input",
            SCATTER,
            ["terrain.heightmap", "height.png"],
            {"scene.toml": scene(terrain='heightmap = "height.png"'), "height.png": "not an image\n"},
        ),
        L(
            "terrain_mesh_zero_area",
            "input",
            SCATTER,
            ["terrain.mesh", "ground.obj"],
            {"scene.toml": scene(terrain='mesh = "ground.obj"'), "ground.obj": flat_quad},
        ),
        L(
            "instances_are_a_csv",
            "input",
            [*RENDER, "--instances", "trees.csv"],
            ["trees.csv", "not a forest instance file", "forest scatter"],
            {"scene.toml": scene(), "trees.csv": "x,y,z\n1,2,3\n"},
        ),
        L(
            "config_is_a_folder",
            "input",
            ["render", "scenes", "-o", "out/frame.exr"],
            ["scenes", "is a folder, not a config file"],
            {"scenes/scene.toml": scene()},
        ),
        L(
            "blender_render_not_png",
            "option",
            ["export", "blender", "scene.toml", "-o", "out/scene.blend", "--render", "out/r.jpg"],
            ["--render", "r.jpg", ".png"],
            {"scene.toml": scene()},
        ),
        L(
            "instances_nan_position",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "position", "NaN"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, edit=edit_nan_position)},
        ),
        L(
            "instances_zero_scale",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "scale", "> 0"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, edit=edit_zero_scale)},
        ),
        L(
            "instances_species_index",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "species"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, edit=edit_species_index)},
        ),
        L(
            "instances_inf_tint",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "tint"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, edit=edit_inf_tint)},
        ),
        L(
            "instances_zero_rotation",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "rotation"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, edit=edit_zero_rotation)},
        ),
        L(
            "instances_partition_index",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "partition"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, edit=edit_partition_index)},
        ),
        L(
            "instances_not_npz",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "not a forest"],
            {"scene.toml": scene(), "trees.npz": b"PK\x03\x04 this is not a zip"},
        ),
        L(
            "instances_other_species",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "species"],
            {"scene.toml": scene(), "trees.npz": _instances(tmp, species=("palm",))},
        ),
        L(
            "instances_missing",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "not found"],
            {"scene.toml": scene()},
        ),
        L(
            "instances_is_folder",
            "input",
            [*RENDER, "--instances", "trees.npz"],
            ["trees.npz", "folder"],
            {"scene.toml": scene(), "trees.npz/keep": "x"},
        ),
        L("config_missing", "input", RENDER, ["scene.toml", "not found"]),
        L("config_not_utf8", "input", SCATTER, ["scene.toml", "cannot read"], {"scene.toml": b"seed = \xff\xfe\n"}),
        L("config_too_big", "input", SCATTER, ["scene.toml", "KiB"], {"scene.toml": big}),
        L("config_nested_2000_deep", "input", SCATTER, ["scene.toml", "nested deeper"], {"scene.toml": deep}),
        # -- species against the library, before scatter -----------------------------------------
        L(
            "species_misspelled_scatter",
            "species",
            SCATTER,
            ["species[0].model", "brodleaf", "broadleaf"],
            {"scene.toml": scene(species='[[species]]\nmodel = "brodleaf"\npercent = 100\n')},
        ),
        L(
            "species_misspelled_render",
            "species",
            RENDER,
            ["species[1].model", "conifr"],
            {
                "scene.toml": scene(
                    species=SPECIES.replace("100", "50") + '[[species]]\nmodel = "conifr"\npercent = 50\n'
                )
            },
        ),
        L(
            "species_unknown_seeded",
            "species",
            SCATTER,
            ["species[0].model", "oak@3"],
            {"scene.toml": scene(species='[[species]]\nmodel = "oak@3"\npercent = 100\n')},
        ),
        L(
            "species_mesh_missing",
            "species",
            SCATTER,
            ["species[0].model", "tree.obj", "not found"],
            {"scene.toml": scene(species='[[species]]\nmodel = "tree.obj"\npercent = 100\n')},
        ),
        # -- values ------------------------------------------------------------------------------
        L(
            "camera_up_zero",
            "value",
            RENDER,
            ["camera.up", "zero"],
            {
                "scene.toml": scene().replace(
                    "target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 0.0]"
                )
            },
        ),
        L(
            "camera_up_along_view",
            "value",
            RENDER,
            ["camera.up", "parallel"],
            {
                "scene.toml": scene().replace(
                    "target = [0.0, 0.0, 0.0]", "target = [0.0, 0.0, 0.0]\nup = [0.0, -30.0, 80.0]"
                )
            },
        ),
        L(
            "camera_target_is_position",
            "value",
            RENDER,
            ["camera.target", "differ"],
            {"scene.toml": scene().replace("target = [0.0, 0.0, 0.0]", "target = [0.0, 30.0, -80.0]")},
        ),
        L(
            "width_as_string",
            "value",
            RENDER,
            ["render.width", "whole number"],
            {"scene.toml": scene().replace("width = 48", 'width = "48"')},
        ),
        L(
            "min_distance_infinite",
            "value",
            SCATTER,
            ["scatter.min_distance", "finite"],
            {"scene.toml": scene().replace("count = 40", "count = 40\nmin_distance = inf")},
        ),
        L(
            "lod_distances_decreasing",
            "value",
            RENDER,
            ["lod.distances", "increasing"],
            {"scene.toml": scene("[lod]\ndistances = [400.0, 80.0]\n")},
        ),
        L(
            "lod_distances_and_pixels",
            "value",
            RENDER,
            ["scene.toml", "lod.pixels", "not both"],
            {"scene.toml": scene("[lod]\ndistances = [80.0, 400.0]\npixels = [200.0, 50.0]\n")},
        ),
        L(
            "sun_colour_negative",
            "value",
            RENDER,
            ["lights.sun.colour", ">= 0"],
            {"scene.toml": scene("[lights]\nsun = { colour = [1.0, -0.5, 1.0] }\n")},
        ),
        L(
            "ground_material_unknown",
            "value",
            SCATTER,
            ["ground.rules[0].material", "moss"],
            {"scene.toml": scene('[ground]\nrules = [{ material = "moss", slope = [0.0, 20.0] }]\n')},
        ),
        L(
            "ground_window_three_values",
            "value",
            RENDER,
            ["ground.rules[0].slope", "[lo, hi]"],
            {"scene.toml": scene('[ground]\nrules = [{ material = "rock", slope = [30.0, 40.0, 90.0] }]\n')},
        ),
        L(
            "ground_rule_map_missing",
            "input",
            RENDER,
            ["ground.rules[0].map", "not found"],
            {"scene.toml": scene('[ground]\nrules = [{ material = "wet", map = "river.png" }]\n')},
        ),
        L(
            "terrain_colour_and_ground_rules",
            "value",
            RENDER,
            ["render.terrain_colour", "[ground]"],
            {"scene.toml": scene('terrain_colour = [0.2, 0.2, 0.2]\n[ground]\nbase = "rock"\n')},
        ),
        L(
            "individuals_zero",
            "value",
            SCATTER,
            ["species[0].individuals", ">= 1"],
            {"scene.toml": scene(species=SPECIES + "individuals = 0\n")},
        ),
        L(
            "colour_jitter_hue_too_large",
            "value",
            RENDER,
            ["species[0].colour_jitter.hue", "<= 180"],
            {"scene.toml": scene(species=SPECIES + "colour_jitter = { hue = 400.0 }\n")},
        ),
        L(
            "colour_normalise_unknown",
            "value",
            SCATTER,
            ["maps.colour_normalise", "'rgb'"],
            {"scene.toml": scene('[maps]\ncolour_normalise = "mean"\n')},
        ),
        L(
            "ground_cover_density_negative",
            "value",
            SCATTER,
            ["ground_cover[0].density", "> 0"],
            {"scene.toml": scene('[[ground_cover]]\nmodel = "grass"\ndensity = -1.0\n')},
        ),
        L(
            "ground_cover_species_misspelled",
            "species",
            SCATTER,
            ["ground_cover[0].model", "fren"],
            {"scene.toml": scene('[[ground_cover]]\nmodel = "fren"\ndensity = 1.0\n')},
        ),
        L(
            "percent_over_100_render",
            "value",
            RENDER,
            ["species", "more than 100"],
            {"scene.toml": scene(species=SPECIES + SPECIES.replace("broadleaf", "palm"))},
        ),
        # -- memory before rendering --------------------------------------------------------------
        L(
            "render_16384_square",
            "memory",
            RENDER,
            ["render.width/render.height", "16384x16384", "fits"],
            {"scene.toml": scene().replace("width = 48\nheight = 27", "width = 16384\nheight = 16384")},
            {"FOREST_MEMORY_GB": MEMORY_GB},
        ),
        L(
            "render_16384_flags",
            "memory",
            [*RENDER, "--width", "16384", "--height", "16384"],
            ["--width/--height", "fits"],
            {"scene.toml": scene()},
            {"FOREST_MEMORY_GB": MEMORY_GB},
        ),
        L(
            "render_sequence_fills_the_disk",
            "memory",
            [
                "render",
                "scene.toml",
                "-o",
                "seq/f_####.exr",
                "--frames",
                "1-10000",
                "--width",
                "16384",
                "--height",
                "16384",
            ],
            ["-o", "seq/f_####.exr", "free on its disk"],
            {"scene.toml": scene()},
        ),
        L(
            "render_bad_memory_setting",
            "memory",
            RENDER,
            ["FOREST_MEMORY_GB"],
            {"scene.toml": scene()},
            {"FOREST_MEMORY_GB": "lots"},
        ),
        # -- option values: one line, never the usage box ------------------------------------------
        L("spp_zero", "option", [*RENDER, "--spp", "0"], ["--spp", ">= 1"], {"scene.toml": scene()}),
        L("width_not_a_number", "option", [*RENDER, "--width", "abc"], ["--width"], {"scene.toml": scene()}),
        L("frames_reversed", "option", [*RENDER, "--frames", "9-2"], ["--frames"], {"scene.toml": scene()}),
        L("frames_garbage", "option", [*RENDER, "--frames", "one-two"], ["--frames"], {"scene.toml": scene()}),
        L(
            "variant_unknown",
            "option",
            [*RENDER, "--variant", "metal"],
            ["--variant", "metal"],
            {"scene.toml": scene()},
        ),
        L("output_option_missing", "option", ["render", "scene.toml"], ["--output"], {"scene.toml": scene()}),
        L("option_misspelled", "option", [*RENDER, "--wdth", "64"], ["--wdth"], {"scene.toml": scene()}),
        L("command_misspelled", "option", ["rendr", "scene.toml"], ["rendr"], {"scene.toml": scene()}),
        L("count_negative_flag", "option", [*SCATTER, "--count", "-5"], ["--count", ">= 0"], {"scene.toml": scene()}),
        L("preview_size_zero", "option", ["library", "preview", "shrub", "--size", "0"], ["--size"]),
        L("preview_lod_unknown", "option", ["library", "preview", "shrub", "--lod", "huge"], ["--lod", "huge"]),
        L("examples_unknown", "option", ["examples", "copy", "rainforest", "copy"], ["rainforest"]),
        # -- library import ---------------------------------------------------------------------
        L(
            "add_zero_area_mesh",
            "library",
            ["library", "add", "flat.obj", "--name", "flat", "--library", "lib"],
            ["flat.obj", "no surface area"],
            {"flat.obj": flat_quad},
        ),
        L(
            "add_nan_mesh",
            "library",
            ["library", "add", "nan.obj", "--name", "bad", "--library", "lib"],
            ["nan.obj", "NaN"],
            {"nan.obj": nan_obj},
        ),
        L(
            "add_huge_mesh",
            "library",
            ["library", "add", "huge.obj", "--name", "bad", "--library", "lib"],
            ["huge.obj", "beyond"],
            {"huge.obj": huge_obj},
        ),
        L(
            "export_rib_frames_backwards_before_scatter",
            "option",
            ["export", "rib", "scene.toml", "-o", "rib", "--frames", "9-1"],
            ["--frames", "9-1"],
            {"scene.toml": scene()},
        ),
        L(
            "export_rib_display_unknown_before_scatter",
            "option",
            ["export", "rib", "scene.toml", "-o", "rib", "--display", "nuke"],
            ["--display", "nuke"],
            {"scene.toml": scene()},
        ),
        L(
            "export_usd_frames_unreadable_before_scatter",
            "option",
            ["export", "usd", "scene.toml", "-o", "s.usda", "--frames", "one"],
            ["--frames", "one"],
            {"scene.toml": scene()},
        ),
        L(
            "export_blender_missing_before_scatter",
            "option",
            ["export", "blender", "scene.toml", "-o", "s.blend", "--blender", "no/blender"],
            ["Blender not found", "no/blender"],
            {"scene.toml": scene()},
        ),
        L(
            "export_usd_instances_missing_before_scatter",
            "option",
            ["export", "usd", "scene.toml", "-o", "s.usda", "--instances", "gone.npz"],
            ["--instances", "gone.npz", "not found"],
            {"scene.toml": scene()},
        ),
        L(
            "seeded_species_by_the_thousand",
            "species",
            ["scatter", "scene.toml", "-o", "trees.npz"],
            ["scene.toml", "species[64].model", "tree variants"],
            {
                "scene.toml": scene(
                    species="".join(f'[[species]]\nmodel = "broadleaf@{i}"\npercent = 0.01\n' for i in range(10_000))
                )
            },
        ),
        # -- unbounded work from a small file (issue 28) ---------------------------------------------
        L(
            "colour_map_huge_dimensions_small_file",
            "input",
            SCATTER,
            ["maps.colour", "colour.png"],
            {"scene.toml": scene('[maps]\ncolour = "colour.png"\n'), "colour.png": _huge_png(16384, 16000)},
        ),
        L(
            "mesh_claims_billions_of_vertices",
            "input",
            SCATTER,
            ["species[0].model", "tree.ply", "cannot read mesh"],
            {"scene.toml": scene(species='[[species]]\nmodel = "tree.ply"\npercent = 100\n'), "tree.ply": HUGE_PLY},
        ),
        L(
            "seeded_species_not_built_over_the_generation_limit",
            "species",
            SCATTER,
            ["scene.toml", "species[16].model", "not built yet"],
            {  # 17 species × 4 individuals: 68 variants no library has built, over the 64 one run may generate
                "scene.toml": scene(
                    species="".join(
                        f'[[species]]\nmodel = "broadleaf@{90_000 + 10 * i}"\npercent = 1\n' for i in range(17)
                    )
                )
            },
        ),
        L(
            "generation_allowance_not_a_number",
            "option",
            SCATTER,
            ["FOREST_ALLOW_GENERATE"],
            {"scene.toml": scene()},
            {"FOREST_ALLOW_GENERATE": "lots"},
        ),
        L(
            "render_within_the_size_limits_over_memory",
            "memory",
            RENDER,
            ["render.width/render.height", "4096x2160", "fits"],
            {"scene.toml": scene().replace("width = 48\nheight = 27", "width = 4096\nheight = 2160")},
            {"FOREST_MEMORY_GB": "1"},
        ),
        L(
            "terrain_size_astronomical",
            "value",
            ["scatter", "scene.toml", "-o", "trees.npz"],
            ["scene.toml", "terrain.flat.size", "1e+07"],
            {"scene.toml": scene(terrain="flat = { size = 1e300 }")},
        ),
        L(
            "camera_at_1e308",
            "value",
            ["render", "scene.toml", "-o", "out.exr"],
            ["scene.toml", "camera.position", "1e+07"],
            {"scene.toml": scene().replace("position = [0.0, 30.0, -80.0]", "position = [0.0, 1e308, -80.0]")},
        ),
        L(
            "terrain_mesh_astronomical",
            "value",
            ["scatter", "scene.toml", "-o", "trees.npz"],
            ["terrain.mesh", "ground.obj", "beyond"],
            {
                "scene.toml": scene(terrain='mesh = "ground.obj"'),
                "ground.obj": _obj([(0, 0, 0), (1e12, 0, 0), (0, 0, 1e12)], [(0, 1, 2)]),
            },
        ),
        L(
            "lod_pixels_increasing",
            "value",
            ["render", "scene.toml", "-o", "out.exr"],
            ["scene.toml", "lod.pixels"],
            {"scene.toml": scene("[lod]\npixels = [20.0, 80.0]\n")},
        ),
        L(
            "add_missing_mesh",
            "library",
            ["library", "add", "gone.obj", "--name", "gone", "--library", "lib"],
            ["gone.obj", "not found"],
        ),
        L(
            "add_bad_name",
            "library",
            ["library", "add", "tri.obj", "--name", "1tree", "--library", "lib"],
            ["--name", "1tree"],
            {"tri.obj": tri_obj},
        ),
        L(
            "add_bad_units",
            "library",
            ["library", "add", "tri.obj", "--name", "tri", "--units", "parsecs", "--library", "lib"],
            ["--units", "parsecs"],
            {"tri.obj": tri_obj},
        ),
        L(
            "add_library_is_file",
            "library",
            ["library", "add", "tri.obj", "--name", "tri", "--library", "lib"],
            ["lib", "folder"],
            {"tri.obj": tri_obj, "lib": "x"},
        ),
        L(
            "add_library_unwritable",
            "library",
            ["library", "add", "tri.obj", "--name", "tri", "--library", f"{UNWRITABLE}/lib"],
            ["--library", "/sys", "cannot write"],
            {"tri.obj": tri_obj},
        ),
        L(
            "build_library_unwritable",
            "library",
            ["library", "build", "--no-previews", "--library", f"{UNWRITABLE}/lib"],
            ["--library", "/sys", "cannot write"],
        ),
        L(
            "build_unknown_species",
            "library",
            ["library", "build", "brodleaf", "--library", "lib"],
            ["brodleaf"],
        ),
        L("preview_unknown_species", "library", ["library", "preview", "brodleaf"], ["brodleaf"]),
        # -- look-dev references ----------------------------------------------------------------
        L(
            "reference_1x1",
            "reference",
            MATCH,
            ["--reference", "ref.png", "1x1"],
            {"scene.toml": scene(), "ref.png": ref_tiny},
        ),
        L(
            "reference_too_small",
            "reference",
            MATCH,
            ["--reference", "ref.png", "10x6"],
            {"scene.toml": scene(), "ref.png": ref_small},
        ),
        L(
            "reference_truncated",
            "reference",
            MATCH,
            ["--reference", "ref.png", "cannot read"],
            {"scene.toml": scene(), "ref.png": trunc_png},
        ),
        L(
            "reference_nan",
            "reference",
            [*MATCH[:3], "ref.exr", *MATCH[4:]],
            ["--reference", "ref.exr", "NaN"],
            {"scene.toml": scene(), "ref.exr": exr_nan},
        ),
        L("reference_missing", "reference", MATCH, ["--reference", "ref.png", "not found"], {"scene.toml": scene()}),
        L(
            "reference_empty",
            "reference",
            MATCH,
            ["--reference", "ref.png", "empty"],
            {"scene.toml": scene(), "ref.png": b""},
        ),
        L(
            "mask_missing",
            "reference",
            [*MATCH, "--mask", "mask.png"],
            ["--mask", "mask.png", "not found"],
            {"scene.toml": scene(), "ref.png": ref_png},
        ),
        L(
            "mask_wrong_aspect",
            "reference",
            [*MATCH, "--mask", "mask.png"],
            ["--mask", "mask.png", "aspect"],
            {"scene.toml": scene(), "ref.png": ref_png, "mask.png": mask_square},
        ),
        L(
            "match_params_unknown",
            "reference",
            [*MATCH, "--params", "colour_map,moon"],
            ["--params", "moon"],
            {"scene.toml": scene(), "ref.png": ref_png},
        ),
        L(
            "match_iterations_zero",
            "reference",
            [*MATCH[:-1], "0"],
            ["--iterations"],
            {"scene.toml": scene(), "ref.png": ref_png},
        ),
        L(
            "match_envmap_nan",
            "reference",
            MATCH,
            ["lights.sky.envmap", "NaN"],
            {"scene.toml": with_sky('envmap = "sky.exr"'), "sky.exr": exr_nan, "ref.png": ref_png},
        ),
    ]
    return out


def _write(folder: Path, rel: str, content: object) -> None:
    p = folder / rel
    p.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(str(content))


def build(dest: str | Path) -> list[Case]:
    """Write every case into ``dest/<name>/`` (files + ``case.json``); return the cases."""
    dest = Path(dest)
    scratch = dest / ".scratch"
    scratch.mkdir(parents=True, exist_ok=True)
    all_cases = cases(scratch)
    scratch.rmdir()
    names = [c.name for c in all_cases]
    if len(set(names)) != len(names):
        raise ValueError("case names must be unique")
    for c in all_cases:
        folder = dest / c.name
        folder.mkdir(parents=True, exist_ok=True)
        for rel, content in c.files.items():
            _write(folder, rel, content)
        meta = {"kind": c.kind, "argv": c.argv, "expect": c.expect, "env": c.env}
        (folder / "case.json").write_text(json.dumps(meta, indent=1) + "\n")
    return all_cases


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: make_corpus.py OUT_DIR")
    built = build(sys.argv[1])
    print(f"{len(built)} cases written to {sys.argv[1]}")
