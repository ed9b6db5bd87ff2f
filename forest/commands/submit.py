"""``forest submit``: send a scene to a forest job service, optionally wait for it and download its outputs.

``forest submit --cancel JOB`` cancels a job.  Ctrl-C while ``--wait`` follows a job stops the waiting only: the
job keeps running on the service, and one line says so and how to cancel it (exit status 130, as for any
interrupted command).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import typer


def progress_line(job: dict[str, Any]) -> str:
    """One farm-readable line for a job's state: ``Progress: 42% running frame 3 (3/8): pass 2/4``.

    Render-farm managers (Deadline, OpenCue, Tractor) read the ``Progress: N%`` at its start.
    """
    percent = int(100 * float(job.get("progress") or 0.0))
    parts = [f"Progress: {percent}%", str(job.get("state", "?"))]
    total = job.get("frames_total") or 0
    if total > 1:
        parts.append(f"frames {job.get('frames_done', 0)}/{total}")
    message = " ".join(str(job.get("message") or "").split())
    if message and job.get("state") == "running" and message != "running":
        parts.append(message[:120])
    eta = job.get("eta_s")
    if eta is not None and job.get("state") == "running":
        parts.append(f"ETA {_duration(float(eta))}")
    return " ".join(parts)


def _duration(seconds: float) -> str:
    s = max(0, round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


def register(app: typer.Typer) -> None:
    """Add ``forest submit`` (queue a job on a ``forest serve`` service) to ``app``."""

    @app.command("submit")
    def submit_cmd(
        scene: Path = typer.Argument(
            None, help="Scene config (TOML); the maps and meshes it names are uploaded (leave out with --cancel)."
        ),
        server: str = typer.Option(
            "http://127.0.0.1:8000",
            "--server",
            envvar="FOREST_SERVER",
            help="The service's URL, e.g. http://farm-head:8000 (also $FOREST_SERVER).",
        ),
        kind: str = typer.Option(
            "render", "--kind", help="render (a still), flythrough, match (colour match), rib or usd (exports)."
        ),
        token: str = typer.Option(
            None,
            "--token",
            envvar="FOREST_SERVICE_TOKEN",
            help="The service's bearer token (also $FOREST_SERVICE_TOKEN).",
        ),
        name: str = typer.Option(None, "--name", help="Job name (default: the config's name)."),
        priority: int = typer.Option(0, "--priority", min=-100, max=100, help="Higher runs first."),
        frames: str = typer.Option(
            None, "--frames", help="Fly-through or export frames: 1-120, 1-120x2, 1,5,9 (default: the camera keys)."
        ),
        frames_per_task: int = typer.Option(None, "--frames-per-task", min=1, help="Frames per fly-through task."),
        width: int = typer.Option(None, "--width", min=1, help="Override the config's render.width."),
        height: int = typer.Option(None, "--height", min=1, help="Override the config's render.height."),
        spp: int = typer.Option(None, "--spp", min=1, help="Override the config's render.spp."),
        variant: str = typer.Option(None, "--variant", help="scalar_rgb, llvm_ad_rgb or cuda_ad_rgb."),
        preview: bool = typer.Option(False, "--preview", help="Render at preview quality."),
        reference: Path = typer.Option(None, "--reference", help="Match jobs: the reference photo (uploaded)."),
        mask: Path = typer.Option(None, "--mask", help="Match jobs: regions painted over the reference (uploaded)."),
        iterations: int = typer.Option(None, "--iterations", min=1, help="Match jobs: optimisation steps."),
        idempotency_key: str = typer.Option(
            None,
            "--idempotency-key",
            help="Submitting again with the same key returns the same job (safe retries from a farm).",
        ),
        wait: bool = typer.Option(
            False, "--wait", "--watch", help="Print 'Progress: N%' lines until the job ends; exit 1 if it fails."
        ),
        output: Path = typer.Option(
            None, "-o", "--output", help="Folder to download the outputs into once the job succeeds (implies --wait)."
        ),
        ext: str = typer.Option(None, "--ext", help="With -o: only outputs ending in .EXT (exr, png, rib …)."),
        interval: float = typer.Option(1.0, "--interval", min=0.1, max=600.0, help="Seconds between progress reads."),
        timeout: float = typer.Option(
            None, "--timeout", min=1.0, help="Give up waiting after this many seconds (the job goes on)."
        ),
        cancel: str = typer.Option(
            None, "--cancel", metavar="JOB", help="Cancel job JOB (its id, as submit printed it) instead of submitting."
        ),
    ):
        """Submit SCENE to a forest service and print the job's id; with --wait, follow it to the end."""
        from ..client import KINDS, ServiceClient
        from ..errors import ForestError, ParameterError
        from ..preflight import input_file, output_folder

        if cancel is not None:
            if scene is not None:
                raise ForestError(f"--cancel: cancels job {cancel}; leave out the scene ({scene})")
            with ServiceClient(server, token=token) as client:
                job = client.cancel(cancel.strip())
            typer.echo(f"job {job.get('id', cancel)}: cancel requested ({job.get('state', '?')})")
            return
        if scene is None:
            raise ForestError("SCENE: give the scene config to submit (or --cancel JOB)")
        if kind not in KINDS:
            raise ForestError(f"--kind: must be one of {', '.join(KINDS)}, got {kind!r}")
        if kind != "match" and (reference is not None or mask is not None or iterations is not None):
            raise ForestError("--reference, --mask and --iterations: apply to --kind match only")
        if kind == "match" and reference is None:
            raise ForestError("--reference: a match job needs a reference photo")
        if ext is not None and output is None:
            raise ForestError("--ext: applies with -o only")
        input_file(scene, field=None, what="config file")
        for flag, photo in (("reference", reference), ("mask", mask)):
            if photo is not None:
                input_file(photo, field=flag, what="image")
        if output is not None:
            try:
                output_folder(output)
            except ParameterError as e:
                raise ForestError(f"-o: {e.message}") from None
        settings = {
            "frames": frames,
            "frames_per_task": frames_per_task,
            "width": width,
            "height": height,
            "spp": spp,
            "variant": variant,
            "preview": preview or None,
            "iterations": iterations,
        }
        with ServiceClient(server, token=token) as client:
            client.health()  # an unreachable server or a wrong token: one line before any upload
            job = client.submit_scene(
                scene,
                kind,
                settings=settings,
                name=name,
                priority=priority,
                reference=reference,
                mask=mask,
                idempotency_key=idempotency_key,
                on_upload=lambda asset, _path: typer.echo(f"uploading {asset}", err=True),
            )
            job_id = job["id"]
            typer.echo(job_id)
            if not (wait or output is not None):
                return
            last: list[tuple[int, str]] = []

            def show(j: dict[str, Any]) -> None:
                key = (int(100 * float(j.get("progress") or 0.0)), str(j.get("state")))
                if key not in last[-1:]:  # a line when the percentage or the state changes
                    last.append(key)
                    typer.echo(progress_line(j))

            try:
                done = client.wait(job_id, interval=interval, timeout=timeout, on_update=show)
            except KeyboardInterrupt:  # only the waiting stops: say so, and how to stop the job too
                typer.echo(
                    f"interrupted: job {job_id} keeps running on the server; "
                    f"cancel it with: forest submit --cancel {job_id} --server {server}",
                    err=True,
                )
                raise typer.Exit(130) from None
            elapsed = done.get("elapsed_s")
            typer.echo(f"job {job_id} succeeded" + (f" in {elapsed:.1f} s" if elapsed is not None else ""))
            if output is not None:
                for path in client.download(job_id, output, ext=ext):
                    typer.echo(f"wrote {path}")
