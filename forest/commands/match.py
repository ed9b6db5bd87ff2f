"""``forest match``: fit a scene's look to a reference photo with the production renderer (look-dev)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import typer

from ..errors import ForestError
from ..progress import COMMAND_HELP as PROGRESS_HELP
from ..progress import command_mode
from . import SET_HELP, load_with_flags


def register(app: typer.Typer) -> None:
    """Add ``forest match`` (look-dev: fit the scene's look to a reference) to ``app``."""

    @app.command("match")
    def match_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        reference: Path = typer.Option(..., "--reference", "-r", help="Reference photo, plate or approved frame."),
        output: Path = typer.Option(..., "-o", "--output", help="Folder for scene.toml, colour_map.exr, report.png."),
        iterations: int = typer.Option(None, "--iterations", help="Gauss–Newton iterations (lookdev.iterations, 8)."),
        resolution: int = typer.Option(
            None, "--resolution", help="Long side of the optimiser's image in pixels (lookdev.resolution, 96)."
        ),
        spp: int = typer.Option(None, "--spp", help="Samples per pixel of the fit's renders (lookdev.spp, 16)."),
        params: str = typer.Option(
            None,
            "--params",
            help="What to fit, some of camera,sun,sky,leaves,ground,haze,colour_map (default: all; colour_map in "
            "aligned mode only).",
        ),
        mode: Literal["aligned", "statistics"] | None = typer.Option(
            None, "--mode", help="aligned (same camera) or statistics (unrelated photo)."
        ),
        mask: Path = typer.Option(
            None,
            "--mask",
            help="Regions painted over the reference: sky #0000ff, canopy #00ff00, ground #ff0000, ignored #000000, "
            "automatic #ffffff.",
        ),
        grid: str = typer.Option(
            None,
            "--grid",
            help="Colour-map cells per side the fit varies, 1 to 64, or auto: the finest grid the reference "
            "resolves (lookdev.grid, auto).",
        ),
        anchor: Literal["auto", "ground", "leaves", "lights", "none"] | None = typer.Option(
            None,
            "--anchor",
            help="What holds the scale of albedos against light: ground, leaves, lights, none or auto "
            "(lookdev.anchor, auto: ground in aligned mode when the frame shows it, else leaves; none in "
            "statistics mode).",
        ),
        map_prior: Literal["edges", "smooth"] | None = typer.Option(
            None,
            "--map-prior",
            help="The colour map's prior: edges (recovers painted patches) or smooth (a smooth correction of the "
            "painted map) (lookdev.map_prior, edges).",
        ),
        instances: Path = typer.Option(None, "--instances", help="A saved InstanceSet (.npz) instead of scattering."),
        variant: Literal["llvm_ad_rgb", "cuda_ad_rgb"] | None = typer.Option(
            None, "--variant", help="Mitsuba variant (default: cuda_ad_rgb where the GPU passed its self-check)."
        ),
        sets: list[str] = typer.Option(None, "--set", metavar="KEY=VALUE", help=SET_HELP),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="No progress bar, no summary."),
        progress: Literal["auto", "bar", "lines", "none"] | None = typer.Option(None, "--progress", help=PROGRESS_HELP),
    ):
        """Fit the colour map and light values so the forest render looks like a reference."""
        command_mode(progress)
        import warnings

        from .. import preflight
        from ..config import referenced_files
        from ..errors import ParameterError
        from ..lookdev import match, optimiser_size, resolve_settings
        from ..lookdev.reference import load_reference, painted_labels
        from ..lookdev.report import WRITTEN
        from ..progress import progress_bar
        from ..render.scene import check_render_inputs
        from ..scene import load_scene

        # Everything a fit needs, checked before the scene is loaded and the production scene built.
        preflight.output_folder(output)
        preflight.input_file(reference, field="reference", what="reference")
        if mask is not None:
            preflight.input_file(mask, field="mask", what="mask")
        cfg = load_with_flags(config, {}, sets)
        inputs = [config, reference, mask, instances, *referenced_files(cfg)]
        preflight.distinct_from_inputs([output / name for name in WRITTEN], inputs)
        if variant is None and cfg.lookdev.variant is None and not quiet:
            from ..render.selfcheck import TIME_LIMIT_S
            from ..render.variant import gpu_check_pending

            if gpu_check_pending():
                typer.echo(f"variant: checking the GPU (once per GPU and driver, at most {TIME_LIMIT_S:g} s)", err=True)
        settings = resolve_settings(
            cfg,
            iterations=iterations,
            resolution=resolution,
            spp=spp,
            params=params,
            mode=mode,
            mask=mask,
            variant=variant,
            grid=grid,
            anchor=anchor,
            map_prior=map_prior,
        )  # bad options fail before any work
        check_render_inputs(cfg)
        width, height = optimiser_size(cfg, settings.resolution)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the fit repeats the reference's notes in its summary
                ref = load_reference(reference, width, height, fit=settings.fit)
        except ParameterError:
            raise
        except ForestError as e:
            raise ParameterError("reference", str(e)) from None
        if settings.mask is not None:
            try:
                painted_labels(settings.mask, ref, width, height, settings.fit)
            except ForestError as e:
                if mask is None:
                    raise cfg.fail("lookdev.mask", str(e)) from None
                raise ParameterError("mask", str(e)) from None
        with progress_bar("scene", quiet=quiet or instances is not None) as bar:
            scene = load_scene(cfg, instances, progress=bar)
        if not quiet:
            seconds, memory = preflight.match_estimate(
                width, height, settings.spp, settings.iterations, settings.variant, settings.mode
            )
            typer.echo(
                f"match: {len(scene.instances):,} trees, {settings.mode} fit of {', '.join(settings.params)}: "
                f"{settings.iterations} iterations x {settings.spp} spp at {width}x{height}, "
                f"{settings.grid if settings.grid == 'auto' else f'{settings.grid}x{settings.grid}'} colour grid "
                f"({settings.variant}): about "
                f"{preflight.format_bytes(memory)}, about {preflight.format_seconds(seconds)}",
                err=True,
            )
            if settings.variant_reason:  # chosen automatically: say why, as forest render does
                typer.echo(f"variant: {settings.variant} ({settings.variant_reason})", err=True)
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
                    anchor=anchor,
                    map_prior=map_prior,
                    progress=bar,
                )
        preflight.record_match(
            settings.variant,
            settings.mode,
            samples=width * height * settings.spp * settings.iterations,
            seconds=result.seconds,
        )
        if not quiet:
            for w in result.warnings:
                typer.echo(f"warning: {w}", err=True)
            f = result.figures
            typer.echo(
                f"objective on a held-out render: start {f['objective_start']:.4g} → fitted {f['objective_fitted']:.4g} "
                f"(iteration {f['best_iteration']}); mean colour difference per pixel (CIEDE2000) "
                f"{f['start_pixel_de_mean']:.2f} → {f['fitted_pixel_de_mean']:.2f}"
            )
            for name, de in f["fitted_regions"].items():
                typer.echo(f"  {name}: CIEDE2000 {f['start_regions'].get(name, float('nan')):.1f} → {de:.1f}")
            for row in result.table:
                note = f"  [{row['flag']}]" if row["flag"] else ""
                typer.echo(
                    f"  {row['label']}: {row['start_shown']} → {row['fitted_shown']}  (range {row['range']}, "
                    f"determined {100 * row['determined']:.0f} %){note}"
                )
            for text in result.weak:
                typer.echo(f"  weak direction: {text}")
            typer.echo(f"fitted {', '.join(result.fitted)} in {result.seconds:.1f} s ({result.variant})")
            for p in result.paths:
                typer.echo(f"wrote {p}")
