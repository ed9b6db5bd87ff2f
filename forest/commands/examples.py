"""``forest examples``: list the example scenes shipped with forest and copy one out to edit and render."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add ``forest examples`` (``list``, ``copy``) to ``app``."""
    ex_app = typer.Typer(
        help="Example scenes shipped with forest (configs and painted maps).",
        no_args_is_help=True,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    app.add_typer(ex_app, name="examples")

    @ex_app.command("list")
    def list_():
        """Print each example's name and the first line of its description."""
        from ..example_scenes import example_names, example_summary

        for name in example_names():
            typer.echo(f"{name:12s} {example_summary(name)}")

    @ex_app.command("copy")
    def copy(
        name: str = typer.Argument(..., help="Example name (see `forest examples list`)."),
        folder: Path = typer.Argument(..., help="Folder to copy the config and its maps into."),
    ):
        """Copy an example's config and every file it refers to into FOLDER; print the config's path."""
        from ..example_scenes import copy_example, example_path
        from ..preflight import output_folder_argument

        example_path(name)  # an unknown name first
        output_folder_argument(folder)
        typer.echo(str(copy_example(name, folder)))
