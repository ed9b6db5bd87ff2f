"""``forest serve``: the render job service (HTTP API, durable queue, web page)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import typer


def _check_port(host: str, port: int) -> None:
    """Refuse a ``--host``/``--port`` this process cannot bind (taken, or not an address of this machine) with one
    line, before anything is created; uvicorn would otherwise print its own error after the banner and exit 3."""
    import socket

    from ..errors import ForestError

    if port == 0:
        return
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except OSError as e:
        raise ForestError(f"--host {host}: cannot resolve it: {e.strerror or e}") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds: a port in TIME_WAIT is free
        try:
            s.bind(address)
        except OSError as e:
            raise ForestError(f"--port {port}: cannot listen on {host}:{port}: {e.strerror or e}") from None


def service_limits(
    *,
    max_side: int | None = None,
    max_pixels: int | None = None,
    max_spp: int | None = None,
    max_trees: int | None = None,
    max_frames: int | None = None,
    max_upload_mb: float | None = None,
):
    """The service's :class:`forest.service.jobs.Limits` with the ``forest serve --max-…`` flags given (None: keep
    the default)."""
    import dataclasses

    from forest.service.jobs import Limits

    given: dict[str, int] = {}
    if max_side is not None:
        given.update(max_width=max_side, max_height=max_side)
    for key, value in (("max_pixels", max_pixels), ("max_spp", max_spp), ("max_trees", max_trees)):
        if value is not None:
            given[key] = value
    if max_frames is not None:
        given["max_frames"] = max_frames
    if max_upload_mb is not None:
        given["max_upload_bytes"] = max(1, int(max_upload_mb * 2**20))
    return dataclasses.replace(Limits(), **given)


def log_config(*, quiet: bool) -> dict:
    """uvicorn's logging set-up for ``forest serve``: its start-up lines are dropped (forest prints its own banner),
    the access log shows unless ``quiet``; warnings and errors always show."""
    import copy

    from uvicorn.config import LOGGING_CONFIG

    cfg = copy.deepcopy(LOGGING_CONFIG)
    cfg["loggers"]["uvicorn"]["level"] = "WARNING"
    cfg["loggers"]["uvicorn.error"] = {"level": "WARNING"}
    cfg["loggers"]["uvicorn.access"]["level"] = "WARNING" if quiet else "INFO"
    cfg["loggers"]["forest.service"] = {"handlers": ["default"], "level": "WARNING", "propagate": False}
    return cfg


def register(app: typer.Typer) -> None:
    """Add ``forest serve`` (the HTTP job service) to ``app``."""

    @app.command("serve")
    def serve_cmd(
        host: str = typer.Option("127.0.0.1", "--host", help="Address to bind; anything but loopback needs --token."),
        port: int = typer.Option(8000, "--port", min=0, max=65535, help="TCP port."),
        data: Path = typer.Option(Path("forest-data"), "--data", help="Data folder: job store, assets, outputs."),
        workers: int = typer.Option(
            1, "--workers", min=0, max=256, help="Tasks run at once (local processes or Ray tasks in flight)."
        ),
        executor: Literal["local", "ray"] = typer.Option("local", "--executor", help="Where tasks run."),
        ray_address: str = typer.Option(
            None,
            "--ray-address",
            help="Ray cluster to join (e.g. ray://head:10001 or auto); default: start a local Ray.",
        ),
        token: str = typer.Option(
            None,
            "--token",
            envvar="FOREST_SERVICE_TOKEN",
            help="Bearer token clients must send (also $FOREST_SERVICE_TOKEN).",
        ),
        max_attempts: int = typer.Option(
            3, "--max-attempts", min=1, max=100, help="Attempts per task before a lost worker fails the job."
        ),
        lease: float = typer.Option(
            15.0, "--lease", min=1.0, help="Seconds without a heartbeat before a task is taken back from its worker."
        ),
        keep_days: float = typer.Option(
            30.0, "--keep-days", min=0.0, help="Forget finished jobs after this many days (their outputs stay)."
        ),
        keep_jobs: int = typer.Option(
            10_000, "--keep-jobs", min=0, help="Forget finished jobs beyond this many (their outputs stay)."
        ),
        keep_events_hours: float = typer.Option(
            1.0, "--keep-events-hours", min=0.0, help="Delete a finished job's event log after this many hours."
        ),
        output_quota: float = typer.Option(
            None,
            "--output-quota",
            min=0.0,
            help="GiB of job folders to keep; beyond it the oldest finished jobs' outputs are deleted.",
        ),
        worker_idle: float = typer.Option(
            600.0,
            "--worker-idle",
            min=1.0,
            help="Seconds an idle local worker keeps its loaded scenes before it exits.",
        ),
        worker_scenes: int = typer.Option(
            1,
            "--worker-scenes",
            min=0,
            max=64,
            help="Loaded scenes each local worker keeps (0: none, reload per task).",
        ),
        worker_nice: int = typer.Option(
            19, "--worker-nice", min=0, max=19, help="CPU niceness of local workers (the service itself stays at 0)."
        ),
        max_side: int = typer.Option(
            None, "--max-side", min=1, max=16384, help="Widest or tallest image a job may ask for [default: 4096]."
        ),
        max_pixels: int = typer.Option(
            None,
            "--max-pixels",
            min=1,
            max=16384 * 16384,
            help="Most pixels (width × height) a job may ask for [default: 4096×2160 = 8847360].",
        ),
        max_spp: int = typer.Option(
            None, "--max-spp", min=1, max=65536, help="Most samples per pixel a job may ask for [default: 1024]."
        ),
        max_trees: int = typer.Option(
            None,
            "--max-trees",
            min=1,
            max=20_000_000,
            help="Most candidate trees ([scatter] count) a job may ask for [default: 2000000].",
        ),
        max_frames: int = typer.Option(
            None, "--max-frames", min=1, max=1_000_000, help="Most frames one job may ask for [default: 2000]."
        ),
        max_upload_mb: float = typer.Option(
            None,
            "--max-upload-mb",
            min=0.001,
            max=65536.0,
            help="Largest upload (map, mesh or photo) in MiB [default: 64].",
        ),
        quiet: bool = typer.Option(
            False, "-q", "--quiet", help="No start-up banner and no access log (warnings and errors still show)."
        ),
    ):
        """Serve the job API and web page: queue renders, fly-throughs and colour matches."""
        from ..errors import ForestError

        if executor not in ("local", "ray"):
            raise ForestError(f"--executor: must be local or ray, got {executor!r}")
        from forest.service.app import ServiceConfig, create_app, is_loopback
        from forest.service.retention import Retention

        if not is_loopback(host) and not token:
            raise ForestError(
                f"--host {host}: binding beyond loopback needs a bearer token (--token or $FOREST_SERVICE_TOKEN)"
            )
        if token is not None and len(token) < 8:
            raise ForestError("--token: use at least 8 characters")
        _check_port(host, port)  # a taken port: one line, before the data folder is made
        if data.exists() and not data.is_dir():
            raise ForestError(f"--data {data}: not a folder")
        try:
            data.mkdir(parents=True, exist_ok=True)
            probe = data / ".write-test"
            probe.write_text("")
            probe.unlink()
        except OSError as e:
            raise ForestError(f"--data {data}: cannot write there: {e.strerror or e}") from None
        from forest.service.assets import DataDir

        held = DataDir(data).lock()
        if held is None:
            raise ForestError(f"--data {data}: another forest service is using this data folder")
        held.close()
        if executor == "ray":
            try:
                import ray  # noqa: F401
            except ImportError:
                raise ForestError(
                    "--executor ray: the ray package is not installed (pip install 'forest[ray]')"
                ) from None
        import uvicorn

        limits = service_limits(
            max_side=max_side,
            max_pixels=max_pixels,
            max_spp=max_spp,
            max_trees=max_trees,
            max_frames=max_frames,
            max_upload_mb=max_upload_mb,
        )
        cfg = ServiceConfig(
            data_dir=data,
            workers=workers,
            executor=executor,
            ray_address=ray_address,
            token=token,
            max_attempts=max_attempts,
            lease_s=lease,
            worker_idle_s=worker_idle,
            worker_scenes=worker_scenes,
            nice=worker_nice,
            limits=limits,
            retention=Retention(
                max_age_s=keep_days * 86400.0,
                max_jobs=keep_jobs,
                events_max_age_s=keep_events_hours * 3600.0,
                output_quota_bytes=int(output_quota * 2**30) if output_quota is not None else None,
            ),
        )
        if not quiet:
            typer.echo(
                f"forest service on http://{host if ':' not in host else f'[{host}]'}:{port}/ "
                f"(data {data.resolve()}, {executor} executor, {workers} worker(s)"
                f"{', token required' if token else ''})",
                err=True,
            )
        os.environ.setdefault("PYTHONUNBUFFERED", "1")
        uvicorn.run(
            create_app(cfg),
            host=host,
            port=port,
            log_config=log_config(quiet=quiet),
            access_log=not quiet,
            timeout_graceful_shutdown=5,
            loop="auto",
            http="auto",
        )
