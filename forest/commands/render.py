"""``forest render``: a still or a frame sequence with Mitsuba 3 (EXR + PNG), a progress bar and a summary."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    @app.command("render")
    def render_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        output: Path = typer.Option(
            ...,
            "-o",
            "--output",
            help="Image to write (.exr; an sRGB .png is written beside it). "
            "With --frames a pattern such as out/frame_####.exr.",
        ),
        preview: bool = typer.Option(
            False,
            "--preview",
            help="Fast look: at most 480 px wide, 8 spp, no motion blur, "
            "denoised when Open Image Denoise is installed.",
        ),
        frames: str = typer.Option(None, "--frames", help="Frames along the camera path: 1-120, 1-120x2, 1,5,9."),
        variant: str = typer.Option(
            None,
            "--variant",
            help="scalar_rgb, llvm_ad_rgb or cuda_ad_rgb (default: the fastest for the scene size and machine).",
        ),
        instances: Path = typer.Option(
            None, "--instances", help="Saved InstanceSet (.npz) from `forest scatter`; default: scatter now."
        ),
        spp: int = typer.Option(None, "--spp", help="Override the config's render.spp."),
        width: int = typer.Option(None, "--width", help="Override the config's render.width."),
        height: int = typer.Option(None, "--height", help="Override the config's render.height."),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="No progress bar, no summary."),
    ):
        """Render the scene's forest with Mitsuba 3: linear EXR (with depth, id and species layers) + sRGB PNG."""
        from ..progress import progress_bar
        from ..render import choose_variant, render_scene
        from ..render.render import output_paths
        from . import load_with_flags

        output_paths(output)  # a bad -o fails before any work
        cfg = load_with_flags(config, {"render.spp": spp, "render.width": width, "render.height": height})
        if variant is not None:
            choose_variant(0, variant)  # reject a bad --variant before any work

        def announce(chosen: str, reason: str) -> None:
            if not quiet:
                typer.echo(f"variant: {chosen} ({reason})", err=True)

        from ..scene import load_scene

        with progress_bar("scene", quiet=quiet or instances is not None) as bar:
            scene = load_scene(cfg, instances, progress=bar)
        with progress_bar("render", quiet=quiet) as bar:
            result = render_scene(
                scene, output=output, variant=variant, frames=frames, preview=preview, progress=bar, announce=announce
            )
        if not quiet:
            if preview:
                typer.echo(
                    "preview: denoised with Open Image Denoise"
                    if result.denoised
                    else "preview: not denoised (install the 'denoise' extra for Open Image Denoise)"
                )
            typer.echo(result.summary())
            exrs = [p for p in result.paths if p.suffix == ".exr"]
            typer.echo(f"wrote {exrs[0]}" if len(exrs) == 1 else f"wrote {len(exrs)} frames: {exrs[0]} … {exrs[-1]}")
