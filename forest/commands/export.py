"""``forest export rib|usd``: the scene for RenderMan (RIB) or any USD pipeline."""

from __future__ import annotations

from pathlib import Path

import typer


def _scene(config: Path, instances: Path | None, library: Path | None, quiet: bool):
    from ..config import load_config
    from ..library import open_library
    from ..progress import progress_bar
    from ..scene import load_scene

    cfg = load_config(config)
    lib = open_library(library) if library is not None else None
    with progress_bar("scene", quiet=quiet or instances is not None) as bar:
        return load_scene(cfg, instances, library=lib, progress=bar)


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def register(app: typer.Typer) -> None:
    export_app = typer.Typer(
        help="Export the scene as RenderMan RIB or USD.",
        no_args_is_help=True,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    app.add_typer(export_app, name="export")

    @export_app.command("rib")
    def rib_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
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
        instances: Path | None = typer.Option(
            None, "--instances", help="A saved InstanceSet (.npz) instead of scattering."
        ),
        library: Path | None = typer.Option(None, "--library", help="Tree library folder."),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="Print nothing on success."),
    ):
        """Archives per species and level, instance files per partition, a scene file per frame."""
        from ..export.rib import export_rib
        from ..progress import progress_bar

        scene = _scene(config, instances, library, quiet)
        with progress_bar("export rib", quiet=quiet) as bar:
            res = export_rib(scene, output, renderman22=renderman22, frames=frames, progress=bar)
        if not quiet:
            typer.echo(
                f"{res.trees:,} trees in {len(res.instance_files)} instance file(s), "
                f"{len(res.archives)} archive(s), {len(res.scenes)} scene file(s), "
                f"{_size(res.bytes)} in {res.seconds:.2f} s"
            )
            typer.echo(f"wrote {output}/ (render from inside it, e.g. {res.scenes[0].name})")

    @export_app.command("usd")
    def usd_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        output: Path = typer.Option(..., "-o", "--output", help="Stage to write: .usda, .usdc or .usd."),
        frames: str | None = typer.Option(
            None, "--frames", help="Frames the camera is sampled at (default: the camera's keyed range, or frame 1)."
        ),
        instances: Path | None = typer.Option(
            None, "--instances", help="A saved InstanceSet (.npz) instead of scattering."
        ),
        library: Path | None = typer.Option(None, "--library", help="Tree library folder."),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="Print nothing on success."),
    ):
        """Terrain, camera, sun and sky, and a PointInstancer per partition over per-species layers."""
        from ..errors import ForestError
        from ..export.usd import SUFFIXES, export_usd
        from ..progress import progress_bar

        if output.suffix.lower() not in SUFFIXES:
            raise ForestError(f"{output}: a USD file name must end in .usda, .usdc or .usd")
        scene = _scene(config, instances, library, quiet)
        with progress_bar("export usd", quiet=quiet) as bar:
            res = export_usd(scene, output, frames=frames, progress=bar)
        if not quiet:
            typer.echo(
                f"{res.trees:,} trees in {len(res.instancers)} point instancer(s), "
                f"{len(res.species_layers)} species layer(s) in {res.seconds:.2f} s"
            )
            typer.echo(f"wrote {output}")
