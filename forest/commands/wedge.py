"""``forest wedge``: the same scene rendered once per value of one config field, each to its own file.

``forest wedge scene.toml --wedge render.exposure=-1,0,1 -o out/w.exr`` renders
three times, as ``forest render`` would with ``--set render.exposure=-1`` and so
on, to ``out/w_exposure_-1.exr``, ``out/w_exposure_0.exr`` and
``out/w_exposure_1.exr`` (each with its PNG).

Values are TOML values separated by commas (``-1,0,1``, ``0.5,1.5``,
``"agx","filmic"``, ``[0,10,0],[0,20,0]``); bare words are strings
(``agx,filmic``).  The file name is the output's with ``_<key>_<value>`` added
before its extension, or before its frame token with ``--frames``
(``out/w.####.exr`` → ``out/w_exposure_-1.####.exr``): ``<key>`` is the last
part of the field's path, ``<value>`` the value with a decimal point written
``p`` (``0.5`` → ``0p5``), an array's items joined by ``_`` and any character
other than a letter, a digit, ``+`` or ``-`` made ``_``.

Every value's config, outputs, disk and memory are checked before the first
render starts, so a bad value (``--wedge render.exposure=0,40``) stops the
wedge with one line naming it and nothing written.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

import typer

from ..progress import COMMAND_HELP as PROGRESS_HELP
from ..progress import command_mode
from . import SET_HELP


def split_wedge(text: str) -> tuple[str, list[tuple[str, Any]]]:
    """``"render.exposure=-1,0,1"`` → ``("render.exposure", [("-1", -1), ("0", 0), ("1", 1)])``.

    Each value comes with its text as given.  The list is read as one TOML array
    (``[0,10,0],[0,20,0]``, ``"agx","filmic"``); when it is none, each
    comma-separated item is read on its own, a bare word as a string.  A
    :class:`~forest.errors.ParameterError` naming ``--wedge`` otherwise.
    """
    import tomllib

    from ..errors import ParameterError
    from . import parse_sets, parse_value

    key, eq, values = str(text).partition("=")
    key = key.strip()
    if not eq or not key or not values.strip():
        raise ParameterError("--wedge", f"{text!r}: use KEY.PATH=V1,V2,…, e.g. render.exposure=-1,0,1")
    try:
        parse_sets([f"{key}=0"])  # the key's spelling, checked as --set checks it
    except ParameterError as e:
        raise ParameterError(f"--wedge {key}", e.message) from None
    try:
        items = tomllib.loads(f"v = [{values}]")["v"]
        return key, [(_text(v), v) for v in items]
    except tomllib.TOMLDecodeError:
        pass
    out = []
    for item in values.split(","):
        try:
            out.append((item.strip(), parse_value(item)))
        except ValueError as e:
            raise ParameterError(f"--wedge {key}", str(e)) from None
    return key, out


def _text(value: Any) -> str:
    """A value as written on the command line (``-1``, ``0.5``, ``true``, ``agx``, ``[0, 10, 0]``)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.12g}"
    if isinstance(value, list):
        return "[" + ", ".join(_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {_text(v)}" for k, v in value.items()) + "}"
    return str(value)


def _label(value: Any) -> str:
    """The file-name form of a value: ``-1``, ``0p5``, ``true``, ``agx``, ``0_10_0``."""
    if isinstance(value, list):
        text = "_".join(_label(v) for v in value)
    elif isinstance(value, dict):
        text = "_".join(f"{k}-{_label(v)}" for k, v in value.items())
    else:
        text = re.sub(r"(?<=\d)\.(?=\d)", "p", _text(value))
    return re.sub(r"_+", "_", re.sub(r"[^A-Za-z0-9+\-]", "_", text)).strip("_")


def wedge_output(output: Path, key: str, value: Any) -> Path:
    """Where the render of ``key`` = ``value`` goes: ``out/w.exr`` → ``out/w_exposure_-1.exr``,
    ``out/w.####.exr`` → ``out/w_exposure_-1.####.exr`` (see the module docstring)."""
    from ..frames import frame_token

    leaf = re.sub(r"\[\d+\]$", "", key.rsplit(".", 1)[-1])
    tag = f"_{leaf}_{_label(value)}".rstrip("_")
    name = output.name
    span = frame_token(name)
    if span is not None:
        head, tail = name[: span[0]], name[span[0] :]
        if head[-1:] in (".", "_"):
            head, tail = head[:-1], head[-1] + tail
    else:
        cut = len(name) - len(output.suffix)
        head, tail = name[:cut], name[cut:]
    return output.with_name(head + tag + tail)


def register(app: typer.Typer) -> None:
    """Add ``forest wedge`` (one render per value of a config field) to ``app``."""

    @app.command("wedge")
    def wedge_cmd(
        config: Path = typer.Argument(..., help="Scene config (TOML)."),
        wedge: str = typer.Option(
            ...,
            "--wedge",
            metavar="KEY=V1,V2,…",
            help="KEY.PATH=V1,V2,…: the config field to vary and its values (TOML values or bare words), "
            "e.g. render.exposure=-1,0,1 or lights.sun.elevation=20,40,60.",
        ),
        output: Path = typer.Option(
            ...,
            "-o",
            "--output",
            help="Image to write (.exr + .png): each value's file gets _<key>_<value> before the extension "
            "(out/w.exr → out/w_exposure_-1.exr); with --frames a pattern such as out/w.####.exr.",
        ),
        sets: list[str] = typer.Option(None, "--set", metavar="KEY=VALUE", help=SET_HELP),
        frames: str = typer.Option(None, "--frames", help="Frames along the camera path: 1-120, 1-120x5, 1,5,9."),
        preview: bool = typer.Option(False, "--preview", help="Fast look, as forest render --preview."),
        variant: Literal["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"] | None = typer.Option(
            None,
            "--variant",
            help="Mitsuba variant (default: [render] variant, else the fastest for the scene and machine).",
        ),
        instances: Path = typer.Option(
            None, "--instances", help="Saved InstanceSet (.npz) from `forest scatter`; default: scatter per value."
        ),
        spp: int = typer.Option(None, "--spp", help="Override the config's render.spp."),
        width: int = typer.Option(None, "--width", help="Override the config's render.width."),
        height: int = typer.Option(None, "--height", help="Override the config's render.height."),
        quiet: bool = typer.Option(False, "-q", "--quiet", help="No progress bar, no summary."),
        progress: Literal["auto", "bar", "lines", "none"] | None = typer.Option(None, "--progress", help=PROGRESS_HELP),
    ):
        """Render the scene once per value of one config field (a wedge), each value to its own file."""
        command_mode(progress)
        from ..errors import ParameterError
        from .render import prepare_render, run_render

        key, values = split_wedge(wedge)
        overrides = {"render.spp": spp, "render.width": width, "render.height": height}
        flag = {"render.spp": "--spp", "render.width": "--width", "render.height": "--height"}.get(key)
        if flag is not None and overrides[key] is not None:
            raise ParameterError(f"--wedge {key}", f"is also given by {flag}; leave one out")
        outputs = [wedge_output(output, key, value) for _, value in values]
        seen: dict[Path, int] = {}
        for i, path in enumerate(outputs):
            if path in seen:
                raise ParameterError(
                    f"--wedge {key}",
                    f"values {seen[path] + 1} and {i + 1} ({values[seen[path]][0]}, {values[i][0]}) both give the "
                    f"file name {path.name}; list each value once",
                )
            seen[path] = i
        # Every value checked (config, outputs, inputs, disk, memory) before the first render.
        plans = [
            prepare_render(
                config,
                path,
                frames=frames,
                variant=variant,
                instances=instances,
                preview=preview,
                overrides=overrides,
                sets=sets,
                labelled={key: (f"--wedge {key}={text}", value)},
            )
            for (text, value), path in zip(values, outputs)
        ]
        written = []
        for i, ((text, _), plan) in enumerate(zip(values, plans)):
            if not quiet:
                typer.echo(f"wedge {i + 1}/{len(plans)}: {key}={text}", err=True)
            result = run_render(plan, quiet=quiet)
            exrs = [p for p in result.paths if p.suffix == ".exr"]
            written.append((text, exrs))
        if quiet:
            return
        typer.echo(f"wedge {key}: {len(written)} renders")
        width_ = max(len(t) for t, _ in written)
        for text, exrs in written:
            where = str(exrs[0]) if len(exrs) == 1 else f"{len(exrs)} frames: {exrs[0]} … {exrs[-1]}"
            typer.echo(f"  {key}={text:<{width_}}  {where}")
