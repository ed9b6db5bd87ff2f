"""CLI sub-commands: one module each, each with ``register(app)``.

Library code reports mistakes by parameter name (:class:`forest.errors.ParameterError`);
:data:`FLAGS` says which command-line flag each parameter comes from, and
:func:`forest.cli.main` prints the flag.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: Parameter (or config field a flag overrides) → the flag a user typed.
FLAGS = {
    "output": "-o",
    "library": "--library",
    "display": "--display",
    "render": "--render",
    "export target": "forest export",
    "frames": "--frames",
    "variant": "--variant",
    "instances": "--instances",
    "reference": "--reference",
    "mask": "--mask",
    "up": "--up",
    "units": "--units",
    "height": "--height",
    "name": "--name",
    "seed": "--seed",
    "scatter.count": "--count",
    "render.spp": "--spp",
    "render.width": "--width",
    "render.height": "--height",
    "lookdev.iterations": "--iterations",
    "lookdev.resolution": "--resolution",
    "lookdev.spp": "--spp",
    "lookdev.params": "--params",
    "lookdev.mode": "--mode",
    "lookdev.mask": "--mask",
    "lookdev.grid": "--grid",
    "lookdev.variant": "--variant",
}


def load_with_flags(path: Path, overrides: dict[str, Any]):
    """Load a config with flag values applied as overrides of their fields (None = not given).

    A bad value from a flag is reported against the flag, not the file.
    """
    from ..config import ConfigError, load_config

    given = {k: v for k, v in overrides.items() if v is not None}
    try:
        return load_config(path, overrides=given)
    except ConfigError as e:
        if e.field in given:
            raise e.for_parameter(e.field) from None
        raise
