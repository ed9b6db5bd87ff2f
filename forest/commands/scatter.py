"""``forest scatter``: config → InstanceSet (.npz) with a printed summary."""

from __future__ import annotations

from pathlib import Path

import typer

from . import SET_HELP


def register(app: typer.Typer) -> None:
    """Add ``forest scatter`` (trees to an InstanceSet ``.npz``) to ``app``."""

    @app.command("scatter")
    def scatter_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        output: Path = typer.Option(..., "-o", "--output", help="InstanceSet file to write (.npz)."),
        seed: int = typer.Option(None, "--seed", help="Override the config's seed."),
        count: int = typer.Option(None, "--count", help="Override [scatter] count."),
        sets: list[str] = typer.Option(None, "--set", metavar="KEY=VALUE", help=SET_HELP),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="No summary, no progress bar."),
    ):
        """Scatter trees over the terrain and save one row per tree as .npz."""
        from .. import preflight
        from ..config import referenced_files
        from ..errors import ParameterError
        from ..library import open_library
        from ..progress import progress_bar
        from ..scatter import scatter
        from . import load_with_flags

        if output.suffix.lower() != ".npz":
            raise ParameterError("output", f"{output}: an InstanceSet is a .npz file")
        preflight.output_file(output)
        cfg = load_with_flags(config, {"seed": seed, "scatter.count": count}, sets)
        preflight.distinct_from_inputs([output], [config, *referenced_files(cfg)])
        preflight.check_species(cfg, open_library())  # a misspelled species fails here, not at render
        with progress_bar("scatter", quiet=quiet) as bar:
            inst, report = scatter(cfg, progress=bar)
        inst.save(output)
        if not quiet:
            for line in report.lines():
                typer.echo(line)
            typer.echo(f"wrote {output}")
