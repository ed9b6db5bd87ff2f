"""``forest library …``: list, build, preview and import tree species."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import typer

from ..errors import ForestError


def _fmt_bounds(b) -> str:
    lo, hi = b
    size = hi - lo
    return f"{size[0]:.2f} x {size[1]:.2f} x {size[2]:.2f} m"


def register(app: typer.Typer) -> None:
    """Add ``forest library`` (``list``, ``build``, ``preview``, ``add``) to ``app``."""
    lib_app = typer.Typer(
        help="The tree library: generated and imported species with levels of detail.",
        no_args_is_help=True,
        context_settings={"help_option_names": ["-h", "--help"]},
    )
    app.add_typer(lib_app, name="library")

    @lib_app.command("list")
    def list_(
        library: Path | None = typer.Option(
            None, "--library", help="User library folder (default: $FOREST_LIBRARY, else the per-user data folder)."
        ),
        as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
    ):
        """Show every species: source, levels of detail with triangle counts, bounds, preview path.

        Lists what is there without building: a generated species whose recipe has no build yet
        is shown as not built (``forest library build`` builds it).
        """
        from ..library import open_library
        from ..library.core import NotBuilt

        lib = open_library(library)
        rows: list[dict[str, Any]] = []
        built = {}
        for name in lib.names():
            try:
                sp = built[name] = lib.get(name, build=False)
            except NotBuilt:
                e = lib.entry(name)
                rows.append({"name": name, "source": str(e.get("source", "generated")), "built": False, "lods": {},
                             "bounds": None, "preview": None, "preview_built": False,
                             "description": str(e.get("description", ""))})  # fmt: skip
                continue
            rows.append(
                {
                    "name": sp.name,
                    "source": sp.source,
                    "built": True,
                    "lods": {l.name: l.triangles for l in sp.lods},
                    "bounds": sp.bounds.tolist(),
                    "preview": str(sp.preview_path),
                    "preview_built": sp.preview_path.is_file(),
                    "description": sp.description,
                }
            )
        if as_json:
            import json

            typer.echo(json.dumps(rows, indent=1))
            return
        from rich.console import Console
        from rich.table import Table

        t = Table(title=f"tree library: {lib.root}")
        for col in ("name", "source", "high", "medium", "low", "far", "size (x × y × z)", "preview"):
            t.add_column(col, justify="right" if col in ("high", "medium", "low", "far") else "left")
        for r in rows:
            if not r["built"]:
                t.add_row(
                    r["name"], r["source"], "–", "–", "–", "–", "not built", "`forest library build " + r["name"] + "`"
                )
                continue
            t.add_row(
                r["name"],
                r["source"],
                *(f"{r['lods'].get(k, 0):,}" for k in ("high", "medium", "low", "far")),
                _fmt_bounds(built[r["name"]].bounds),
                r["preview"] + ("" if r["preview_built"] else " (not rendered)"),
            )
        Console(width=200).print(t)

    @lib_app.command("build")
    def build(
        names: list[str] | None = typer.Argument(None, help="Species to build (default: all)."),
        library: Path | None = typer.Option(None, "--library", help="Library folder."),
        no_previews: bool = typer.Option(False, "--no-previews", help="Skip rendering previews."),
        prune: bool = typer.Option(
            False,
            "--prune",
            help="Remove cached species no current recipe makes (the cache is shared by every install).",
        ),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
    ):
        """Generate every species' levels of detail and previews into the user library's cache (skips fresh ones)."""
        import time

        from .. import preflight
        from ..library import open_library
        from ..progress import progress_bar

        lib = open_library(library)
        for n in names or []:
            lib.entry(n)
        preflight.output_folder(lib.cache, field="library")  # the build writes there: check before generating
        t0 = time.perf_counter()
        stale = [n for n in (names or lib.names()) if not lib.is_fresh(n)]
        with progress_bar("library", quiet=quiet) as progress:
            built = lib.build(names or None, previews=not no_previews, progress=progress, prune=prune)
        if not quiet:
            typer.echo(
                f"{len(built)} species ready ({len(stale)} rebuilt) in {time.perf_counter() - t0:.1f} s "
                f"under {lib.cache}"
            )

    @lib_app.command("preview")
    def preview(
        name: str = typer.Argument(..., help="Species name (or NAME@SEED)."),
        library: Path | None = typer.Option(None, "--library", help="Library folder."),
        lod: Literal["high", "medium", "low", "far"] = typer.Option("high", "--lod", help="Level of detail to render."),
        output: Path | None = typer.Option(None, "--output", "-o", help="Write here instead of the cache."),
        size: int = typer.Option(192, "--size", min=16, max=2048, help="Image width and height in pixels."),
        spp: int = typer.Option(16, "--spp", min=1, max=4096, help="Samples per pixel."),
    ):
        """(Re)render a species' preview image with Mitsuba and print its path."""
        from .. import preflight
        from ..library import open_library
        from ..library.preview import render_preview_file

        if lod not in ("high", "medium", "low", "far"):
            raise ForestError(f"--lod: must be one of high, medium, low, far; got {lod!r}")
        if output is not None:
            if output.suffix.lower() != ".png":
                raise ForestError(f"-o: {output}: a preview is a .png file")
            preflight.output_file(output)
        lib = open_library(library)
        sp = lib.resolve(name)
        path = output or sp.preview_path
        if output is None and (lod != "high" or size != 192 or spp != 16):
            path = sp.preview_path.with_name(f"{sp.preview_path.stem}-{lod}-{size}-{spp}.png")
        render_preview_file(sp, path, lod=lod, size=(size, size), spp=spp)
        typer.echo(str(path))

    @lib_app.command("add")
    def add(
        mesh: Path = typer.Argument(..., help="Mesh file: OBJ (with MTL materials), PLY, glTF/GLB, STL."),
        name: str = typer.Option(..., "--name", "-n", help="Species name to add to the manifest."),
        library: Path | None = typer.Option(None, "--library", help="Library folder."),
        up: Literal["auto", "y", "z"] = typer.Option(
            "auto", "--up", help="The file's up axis (auto: z for STL, y otherwise)."
        ),
        units: Literal["auto", "m", "cm", "mm", "in", "ft"] = typer.Option("auto", "--units", help="The file's unit."),
        height: float | None = typer.Option(
            None, "--height", min=0.0, help="Scale the model to this height in metres."
        ),
        force: bool = typer.Option(False, "--force", help="Replace an existing species of that name."),
        quiet: bool = typer.Option(False, "--quiet", "-q", help="Print only the species' name."),
    ):
        """Import a mesh as a species: normalise it, derive levels of detail, measure bounds, render a preview."""
        from .. import preflight
        from ..library import open_library
        from ..library.importer import add_species, missing_references

        preflight.input_file(mesh, field=None, what="mesh file")
        lib = open_library(library)
        preflight.output_folder(lib.root, field="library")  # the import writes there: check before converting
        sp = add_species(lib, mesh, name, up=up, units=units, height=height, force=force)
        for line in missing_references(Path(mesh)):
            typer.echo(f"warning: {line}", err=True)
        if quiet:
            typer.echo(sp.name)
            return
        typer.echo(
            f"added {sp.name}: "
            + ", ".join(f"{l.name} {l.triangles:,}" for l in sp.lods)
            + f" triangles; {_fmt_bounds(sp.bounds)}; preview {sp.preview}"
        )
