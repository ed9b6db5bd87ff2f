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
        """Print each example's name and its whole description (one line each when not on a terminal)."""
        import shutil
        import sys

        from ..example_scenes import example_names

        width = shutil.get_terminal_size().columns if sys.stdout.isatty() else None
        for name in example_names():
            typer.echo(listing_entry(name, example_description(name), width))

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


#: Width of the name column of ``forest examples list``.
NAME_WIDTH = 12


def example_description(name: str) -> str:
    """The description of example ``name``: its config's leading comment, up to the commands it shows
    (comment lines indented by two or more spaces) or the first line that is not a comment, on one line."""
    from ..example_scenes import example_path

    words: list[str] = []
    for line in example_path(name).read_text().splitlines():
        if not line.startswith("#"):
            if words or line.strip():
                break
            continue
        text = line[1:]
        if text.startswith("  ") and text.strip():  # an example command, not prose
            break
        words += text.split()
    return " ".join(words)


def listing_entry(name: str, description: str, width: int | None = None) -> str:
    """``name`` and ``description`` as one entry of the list: one line, or wrapped to ``width`` columns under a
    hanging indent."""
    import textwrap

    first = f"{name:{NAME_WIDTH}s} "
    if width is None or not description:
        return (first + description).rstrip()
    return textwrap.fill(
        description,
        width=max(width - 1, len(first) + 20),
        initial_indent=first,
        subsequent_indent=" " * len(first),
        break_on_hyphens=False,
    )
