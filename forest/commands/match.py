"""``forest match``: fit the colour map and lights to a reference photo (look-dev)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("match")
    def match_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        reference: Path = typer.Option(..., "--reference", "-r", help="Reference photo, plate or approved frame."),
        output: Path = typer.Option(..., "-o", "--output", help="Folder for scene.toml, colour_map.exr, report.png."),
        iterations: int = typer.Option(None, "--iterations", help="Optimiser iterations (lookdev.iterations, 200)."),
        resolution: int = typer.Option(
            None, "--resolution", help="Long side of the optimiser's image in pixels (lookdev.resolution, 96)."
        ),
        spp: int = typer.Option(None, "--spp", help="Samples per pixel per iteration (lookdev.spp, 8)."),
        params: str = typer.Option(
            None, "--params", help="What to fit: colour_map,sun,sky[,sun_direction] (default colour_map,sun,sky)."
        ),
        mode: str = typer.Option(None, "--mode", help="aligned (same camera) or statistics (unrelated photo)."),
        mask: Path = typer.Option(None, "--mask", help="Grey image over the reference: black pixels are ignored."),
        grid: int = typer.Option(None, "--grid", help="Colour-map cells per side, 1 to 64 (lookdev.grid, 16)."),
        instances: Path = typer.Option(None, "--instances", help="A saved InstanceSet (.npz) instead of scattering."),
        variant: str = typer.Option(None, "--variant", help="llvm_ad_rgb or cuda_ad_rgb (default: cuda if present)."),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="No progress bar, no summary."),
    ):
        """Fit the colour map and light values so the forest render looks like a reference."""
        import warnings

        from ..config import load_config
        from ..lookdev import match
        from ..progress import progress_bar
        from ..scene import load_scene

        cfg = load_config(config)
        from ..lookdev import resolve_settings

        resolve_settings(
            cfg,
            iterations=iterations,
            resolution=resolution,
            spp=spp,
            params=params,
            mode=mode,
            mask=mask,
            variant=variant,
            grid=grid,
        )  # bad options fail before any work
        with progress_bar("scene", quiet=quiet or instances is not None) as bar:
            scene = load_scene(cfg, instances, progress=bar)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with progress_bar("match", quiet=quiet) as bar:
                result = match(
                    scene,
                    reference,
                    output,
                    iterations=iterations,
                    resolution=resolution,
                    spp=spp,
                    params=params,
                    mode=mode,
                    mask=mask,
                    variant=variant,
                    grid=grid,
                    progress=bar,
                )
        if not quiet:
            for w in result.warnings:
                typer.echo(f"warning: {w}", err=True)
            f = result.figures
            typer.echo(
                f"colour error (CIEDE2000): start mean {f['start_delta_e_mean']:.2f} / p95 "
                f"{f['start_delta_e_p95']:.2f} → result mean {f['result_delta_e_mean']:.2f} / p95 "
                f"{f['result_delta_e_p95']:.2f}"
            )
            for k, v in result.result.light_values().items():
                typer.echo(f"  {k}: {result.start.light_values().get(k, float('nan')):.4g} → {v:.4g}")
            typer.echo(f"fitted {', '.join(result.fitted)} in {result.seconds:.1f} s ({result.variant})")
            for p in result.paths:
                typer.echo(f"wrote {p}")
