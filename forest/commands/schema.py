"""``forest schema``: the scene file's JSON Schema, for editors that complete and check TOML."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add ``forest schema`` (the scene files' JSON Schema) to ``app``."""

    @app.command("schema")
    def schema_cmd(
        output: Path | None = typer.Option(None, "-o", "--output", help="Write to this file instead of stdout."),
    ):
        """Print the JSON Schema of scene files (point your editor's TOML plug-in at it)."""
        import json

        from ..atomic import atomic_path
        from ..config.schema import SceneConfig
        from ..preflight import output_file

        text = json.dumps(SceneConfig.model_json_schema(), indent=2, sort_keys=True) + "\n"
        if output is None:
            typer.echo(text, nl=False)
            return
        output_file(output)
        with atomic_path(output) as tmp:
            tmp.write_text(text)
        typer.echo(f"wrote {output}", err=True)
