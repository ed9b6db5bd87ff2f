"""``forest render``: a still or a frame sequence with Mitsuba 3 (EXR + PNG), a progress bar and a summary."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import typer

from ..progress import COMMAND_HELP as PROGRESS_HELP
from ..progress import command_mode
from . import SET_HELP


def register(app: typer.Typer) -> None:
    """Add ``forest render`` (a still or a frame sequence) to ``app``."""

    @app.command("render")
    def render_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        output: Path = typer.Option(
            ...,
            "-o",
            "--output",
            help="Image to write (.exr; an sRGB .png is written beside it). "
            "With --frames a pattern such as out/frame_####.exr (without, a pattern names the still as frame 1).",
        ),
        preview: bool = typer.Option(
            False,
            "--preview",
            help="Fast look: at most 480 px wide, 8 spp, no motion blur, "
            "denoised when Open Image Denoise is installed.",
        ),
        frames: str = typer.Option(None, "--frames", help="Frames along the camera path: 1-120, 1-120x2, 1,5,9."),
        variant: Literal["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"] | None = typer.Option(
            None,
            "--variant",
            help="Mitsuba variant (default: [render] variant, else the fastest for the scene and machine).",
        ),
        instances: Path = typer.Option(
            None, "--instances", help="Saved InstanceSet (.npz) from `forest scatter`; default: scatter now."
        ),
        spp: int = typer.Option(None, "--spp", help="Override the config's render.spp."),
        width: int = typer.Option(None, "--width", help="Override the config's render.width."),
        height: int = typer.Option(None, "--height", help="Override the config's render.height."),
        sets: list[str] = typer.Option(None, "--set", metavar="KEY=VALUE", help=SET_HELP),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="No progress bar, no summary."),
        progress: Literal["auto", "bar", "lines", "none"] | None = typer.Option(None, "--progress", help=PROGRESS_HELP),
    ):
        """Render the scene's forest with Mitsuba 3: linear EXR (with depth, id and species layers) + sRGB PNG."""
        command_mode(progress)
        plan = prepare_render(
            config,
            output,
            frames=frames,
            variant=variant,
            instances=instances,
            preview=preview,
            overrides={"render.spp": spp, "render.width": width, "render.height": height},
            sets=sets,
        )
        run_render(plan, quiet=quiet)


@dataclass
class RenderPlan:
    """A render checked and ready to start: the config with its overrides, the frames and every file it writes.

    Made by :func:`prepare_render` (all the checks that need no trees), run by :func:`run_render`.
    """

    config_path: Path
    config: Any  # forest.config.Config
    output: Path
    frames: list[int] | None  # None: a still
    targets: list[Path]  # every EXR and PNG written
    instances: Path | None
    variant: str | None
    preview: bool
    size_from_flags: bool  # --width/--height (or --set render.width/height) gave the size


def prepare_render(
    config: Path,
    output: Path,
    *,
    frames: str | None = None,
    variant: str | None = None,
    instances: Path | None = None,
    preview: bool = False,
    overrides: dict[str, Any] | None = None,
    sets: list[str] | None = None,
    labelled: dict[str, tuple[str, Any]] | None = None,
) -> RenderPlan:
    """Everything ``forest render`` checks before it reads a tree: outputs, flags, config, inputs, disk, memory.

    ``overrides``: config fields from the command's own flags (None: not given); ``sets``: ``--set`` items;
    ``labelled``: more overrides with the flag each comes from (see :func:`forest.commands.load_with_flags`).
    Raises a :class:`~forest.errors.ForestError` (one line) for any mistake; writes nothing.
    """
    from .. import preflight
    from ..frames import still_path

    if frames is None:  # a still to a pattern (f.%04d.exr) is frame 1 named by it
        output = Path(still_path(str(output)))
    if frames is None and output.suffix.lower() in (".exr", ".png"):
        # The still's EXR and PNG, checked before the renderer's modules are even imported.
        preflight.output_files(
            [
                output.with_suffix(output.suffix),
                output.with_suffix(".png" if output.suffix.lower() == ".exr" else ".exr"),
            ]
        )

    from ..config import referenced_files
    from ..errors import ParameterError
    from ..frames import frame_path, parse_frames
    from ..render import choose_variant
    from ..render.render import frame_size, output_paths
    from ..render.scene import check_render_inputs
    from . import load_with_flags, parse_sets

    overrides = overrides or {}
    # 1. What can be checked without reading the scene: the output files and the flags.
    frame_list = parse_frames(frames) if frames is not None else [1]
    if frames is None:
        targets = list(output_paths(output))
    else:
        targets = [p for f in frame_list for p in output_paths(frame_path(str(output), f))]
        if len(set(targets)) != len(targets):
            raise ParameterError("output", f"{output}: every frame needs its own file; put #### in the name")
    preflight.output_files(targets)
    cfg = load_with_flags(config, overrides, sets, labelled=labelled)
    preflight.distinct_from_inputs(targets, [config, instances, *referenced_files(cfg)])
    if variant is not None:
        choose_variant(0, variant)  # reject a bad --variant before any work
    # 2. The inputs only the render reads, the disk, and the image's memory before any tree is loaded.
    check_render_inputs(cfg)
    size = frame_size(cfg, preview=preview)
    pixels = size.width * size.height
    preflight.check_free_space(output, len(frame_list) * pixels * preflight.FRAME_BYTES_PER_PIXEL)
    sized = {"render.width", "render.height"}
    flags = any(overrides.get(k) is not None for k in sized) or bool(sized & {*parse_sets(sets), *(labelled or {})})
    guess = variant or cfg.render.variant or "scalar_rgb"
    preflight.check_render_memory(
        cfg, preflight.render_estimate(size.width, size.height, size.spp, 0, guess), flags=flags
    )
    return RenderPlan(
        config_path=config,
        config=cfg,
        output=output,
        frames=frame_list if frames is not None else None,
        targets=targets,
        instances=instances,
        variant=variant,
        preview=preview,
        size_from_flags=flags,
    )


def run_render(plan: RenderPlan, *, quiet: bool = False) -> Any:
    """Load the scene of a :func:`prepare_render` plan, check the whole render's memory, render it and
    (unless ``quiet``) print the variant, the estimate and the summary; returns the
    :class:`~forest.render.render.RenderResult`."""
    from .. import preflight
    from ..camera import under_ground
    from ..progress import progress_bar
    from ..render import choose_variant, render_scene
    from ..render.render import frame_size
    from ..scene import load_scene

    cfg, variant, instances, preview = plan.config, plan.variant, plan.instances, plan.preview
    frame_list = plan.frames if plan.frames is not None else [1]
    size = frame_size(cfg, preview=preview)
    with progress_bar("scene", quiet=quiet or instances is not None) as bar:
        scene = load_scene(cfg, instances, progress=bar)
    # 3. With the trees known: the whole render's memory, then say what will happen.
    below = under_ground(cfg.camera, scene.terrain.height_at, [float(f) for f in frame_list])
    if below is not None:
        typer.echo(f"warning: {below}", err=True)
    trees = len(scene.instances)
    if variant is None and cfg.render.variant is None and not quiet:
        from ..render.selfcheck import TIME_LIMIT_S
        from ..render.variant import gpu_check_pending

        if gpu_check_pending():
            typer.echo(f"variant: checking the GPU (once per GPU and driver, at most {TIME_LIMIT_S:g} s)", err=True)
    chosen, reason = choose_variant(trees, variant, cfg.render.variant)
    estimate = preflight.scene_render_estimate(scene, chosen, [float(f) for f in frame_list], size)
    room = preflight.memory_room()  # with the cgroup limit that binds, named in the lines below
    preflight.check_render_memory(cfg, estimate, available=room, flags=plan.size_from_flags)
    if not quiet:
        typer.echo(f"render: {estimate.line(room)}", err=True)
        typer.echo(f"variant: {chosen} ({reason})", err=True)
    with progress_bar("render", quiet=quiet) as bar:
        result = render_scene(
            scene, output=plan.output, variant=variant, frames=plan.frames, preview=preview, progress=bar
        )
    preflight.record_render(
        result.variant,
        samples=len(result.frames) * result.width * result.height * max(result.spp, result.subframes),
        trees=result.trees,
        render_seconds=result.render_seconds,
        load_seconds=result.load_seconds,
    )
    if not quiet:
        if preview:
            typer.echo(
                "preview: denoised with Open Image Denoise"
                if result.denoised
                else "preview: not denoised (install the 'denoise' extra for Open Image Denoise)"
            )
        elif result.denoised:
            typer.echo("denoised with Open Image Denoise (guided by first-hit albedo and normal)")
        typer.echo(result.summary())
        exrs = [p for p in result.paths if p.suffix == ".exr"]
        typer.echo(f"wrote {exrs[0]}" if len(exrs) == 1 else f"wrote {len(exrs)} frames: {exrs[0]} … {exrs[-1]}")
    return result
