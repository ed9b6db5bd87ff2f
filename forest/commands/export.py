"""``forest export rib|usd|blender|points``: the scene for RenderMan, USD pipelines, Blender and any DCC."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer
from typer.core import TyperGroup

from . import SET_HELP

TARGETS = ("rib", "usd", "blender", "points")


class ExportGroup(TyperGroup):
    """``forest export`` with an unknown target is a user mistake: one line naming it, exit 2."""

    def resolve_command(self, ctx: Any, args: list[str]):
        """Click's command lookup, refusing a first argument that names no target with a ``ParameterError``."""
        name = args[0] if args else None
        if name is not None and not name.startswith("-") and self.get_command(ctx, name) is None:
            from ..errors import ParameterError

            raise ParameterError("export target", f"unknown target {name!r}; use one of {', '.join(TARGETS)}")
        return super().resolve_command(ctx, args)


def _scene(
    config: Path,
    instances: Path | None,
    library: Path | None,
    quiet: bool,
    *,
    files: tuple[Path | None, ...] = (),
    folder: Path | None = None,
    frames: str | None = None,
    check: Any = None,
    sets: list[str] | None = None,
):
    """The Scene to export, after the outputs and options are checked (before any scatter): the ``files`` the
    export writes, or the ``folder`` it writes into, writable and none of them one of its inputs; ``--frames``
    readable; ``check(config)``, the command's own checks of its options against the config; ``sets``: ``--set``
    items applied to the config."""
    from .. import preflight
    from ..config import referenced_files
    from ..frames import parse_frames
    from ..library import open_library
    from ..progress import progress_bar
    from ..scene import load_scene
    from . import load_with_flags

    if frames is not None and not parse_frames(frames):
        from ..errors import ParameterError

        raise ParameterError("frames", "no frames selected")
    if instances is not None:
        preflight.input_file(instances, field="instances", what="instance file")
    outputs = [f for f in files if f is not None]
    if folder is not None:
        preflight.output_folder(folder)
    preflight.output_files(outputs)
    cfg = load_with_flags(config, {}, sets)
    preflight.distinct_from_inputs(outputs, [config, instances, *referenced_files(cfg)])
    if check is not None:
        check(cfg)
    lib = open_library(library) if library is not None else None
    with progress_bar("scene", quiet=quiet or instances is not None) as bar:
        return load_scene(cfg, instances, library=lib, progress=bar)


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


CONFIG = typer.Argument(..., help="Scene config (TOML).")
INSTANCES = typer.Option(None, "--instances", help="A saved InstanceSet (.npz) instead of scattering.")
LIBRARY = typer.Option(None, "--library", help="Tree library folder.")
QUIET = typer.Option(False, "-q", "--quiet", help="Print nothing on success.")
SETS = typer.Option(None, "--set", metavar="KEY=VALUE", help=SET_HELP)


def register(app: typer.Typer) -> None:
    """Add ``forest export`` (``rib``, ``usd``, ``blender``, ``points``) to ``app``."""
    export_app = typer.Typer(
        cls=ExportGroup,
        help="Export the scene as RenderMan RIB, USD, a Blender file or points for any DCC.",
        no_args_is_help=True,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    app.add_typer(export_app, name="export")

    @export_app.command("rib")
    def rib_cmd(
        config: Path = CONFIG,
        output: Path = typer.Option(..., "-o", "--output", help="Folder to write the RIB files into."),
        frames: str | None = typer.Option(
            None,
            "--frames",
            help="Frames, e.g. 1-120, 1-120x2 or 1,5,9 (default: the camera's keyed range, or frame 1).",
        ),
        renderman22: bool = typer.Option(
            False,
            "--renderman22",
            help="RenderMan 22+ style: Procedural2, PxrDistantLight/PxrDomeLight, PxrSurface reading Cs.",
        ),
        display: str | None = typer.Option(
            None,
            "--display",
            help="Display driver: file (default: TIFF, every renderer), tiff, openexr, exr, png, framebuffer, it.",
        ),
        instances: Path | None = INSTANCES,
        library: Path | None = LIBRARY,
        sets: list[str] | None = SETS,
        quiet: bool = QUIET,
    ):
        """Objects, archives per species and level, textures, instance files, a scene file per frame."""
        from ..export.rib import export_rib, rib_options
        from ..progress import progress_bar

        scene = _scene(config, instances, library, quiet, folder=output, frames=frames, sets=sets,
                       check=lambda cfg: rib_options(cfg, renderman22, display))  # fmt: skip
        with progress_bar("export rib", quiet=quiet) as bar:
            res = export_rib(scene, output, renderman22=renderman22, frames=frames, display=display, progress=bar)
        if not quiet:
            n_inst = len({p for ps in res.frame_instance_files.values() for p in ps})
            typer.echo(
                f"{res.trees:,} trees in {n_inst} instance file(s), "
                f"{len(res.archives)} archive(s), {len(res.textures)} texture(s), {len(res.scenes)} scene file(s), "
                f"{_size(res.bytes)} in {res.seconds:.2f} s"
            )
            first = res.scenes[0].name
            step = "sh prepare.sh once, then render" if not renderman22 or res.textures else "render"
            typer.echo(f"wrote {output}/ ({step} from inside it, e.g. {first})")

    @export_app.command("usd")
    def usd_cmd(
        config: Path = CONFIG,
        output: Path = typer.Option(..., "-o", "--output", help="Stage to write: .usda, .usdc or .usd."),
        frames: str | None = typer.Option(
            None, "--frames", help="Frames the camera is sampled at (default: the camera's keyed range, or frame 1)."
        ),
        instances: Path | None = INSTANCES,
        library: Path | None = LIBRARY,
        sets: list[str] | None = SETS,
        quiet: bool = QUIET,
    ):
        """Terrain, camera, sun and sky, and a PointInstancer per partition over per-species layers."""
        from ..errors import ForestError
        from ..export.usd import SUFFIXES, export_usd
        from ..progress import progress_bar

        if output.suffix.lower() not in SUFFIXES:
            raise ForestError(f"{output}: a USD file name must end in .usda, .usdc or .usd")
        scene = _scene(config, instances, library, quiet, files=(output,), frames=frames, sets=sets)
        with progress_bar("export usd", quiet=quiet) as bar:
            res = export_usd(scene, output, frames=frames, progress=bar)
        if not quiet:
            typer.echo(
                f"{res.trees:,} trees in {len(res.instancers)} point instancer(s), "
                f"{len(res.species_layers)} species layer(s) in {res.seconds:.2f} s"
            )
            typer.echo(f"wrote {output}")

    @export_app.command("blender")
    def blender_cmd(
        config: Path = CONFIG,
        output: Path = typer.Option(..., "-o", "--output", help="Blender file to write (.blend)."),
        frames: str | None = typer.Option(
            None, "--frames", help="Frames the camera is keyed at (default: the camera's keyed range, or frame 1)."
        ),
        render: Path | None = typer.Option(
            None, "--render", help="Also render the scene in Cycles to this PNG (the scene's [render] settings)."
        ),
        blender: str | None = typer.Option(
            None, "--blender", help="Blender executable (default: $FOREST_BLENDER, else blender on PATH)."
        ),
        instances: Path | None = INSTANCES,
        library: Path | None = LIBRARY,
        sets: list[str] | None = SETS,
        quiet: bool = QUIET,
    ):
        """Species meshes and materials once, the trees as Geometry Nodes instances, camera, sun and sky."""
        from ..errors import ParameterError
        from ..export.blender import export_blender, find_blender
        from ..progress import progress_bar

        if output.suffix.lower() != ".blend":
            raise ParameterError("output", f"{output}: a Blender file name must end in .blend")
        if render is not None and render.suffix.lower() != ".png":  # Cycles' frame is written as a PNG
            raise ParameterError("render", f"{render}: the Cycles render is a PNG; the name must end in .png")
        find_blender(blender)  # before the scatter: a missing Blender is known now
        scene = _scene(config, instances, library, quiet, files=(output, render), frames=frames, sets=sets)
        with progress_bar("export blender", quiet=quiet) as bar:
            res = export_blender(scene, output, blender=blender, frames=frames, render=render, progress=bar)
        if not quiet:
            typer.echo(
                f"{res.trees:,} trees as instances of {len(res.species)} species in {res.seconds:.2f} s "
                f"(Blender {res.blender_seconds:.2f} s)"
            )
            typer.echo(f"wrote {output}" + (f" and {render}" if render else ""))

    @export_app.command("points")
    def points_cmd(
        config: Path = CONFIG,
        output: Path = typer.Option(..., "-o", "--output", help="Points file: .usda, .usd, .usdc, .ply or .csv."),
        instances: Path | None = INSTANCES,
        library: Path | None = LIBRARY,
        sets: list[str] | None = SETS,
        quiet: bool = QUIET,
    ):
        """One point per tree with P, orient (x,y,z,w), pscale, id, species and Cd, for any DCC to instance."""
        from ..errors import ParameterError
        from ..export.points import SUFFIXES, export_points

        if output.suffix.lower() not in SUFFIXES:
            raise ParameterError("output", f"{output}: a points file must end in {', '.join(SUFFIXES)}")
        scene = _scene(config, instances, library, quiet, files=(output,), sets=sets)
        res = export_points(scene, output)
        if not quiet:
            typer.echo(f"{res.trees:,} points in {res.seconds:.2f} s")
            typer.echo(f"wrote {output}")
