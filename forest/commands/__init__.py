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


#: Help of ``--set`` (every command that reads a scene config has it).
SET_HELP = (
    'Set a config field for this run: KEY.PATH=VALUE, the value as TOML (16, -0.5, true, [0,10,0], "agx") '
    "or a bare word; repeatable, e.g. --set render.spp=16 --set 'camera.position=[0,10,0]'."
)


def parse_value(text: str) -> Any:
    """A command-line value read as a TOML value (``16``, ``-0.5``, ``true``, ``[0, 10, 0]``, ``"agx"``, ``{a = 1}``).

    Anything that is no TOML value is taken as a bare string (``agx``, ``grade``), unless it
    starts as an array, a table or a quoted string: that is a mistake, a :class:`ValueError`.
    """
    import tomllib

    text = text.strip()
    try:
        data = tomllib.loads(f"v = {text}")
    except tomllib.TOMLDecodeError as e:
        if text[:1] in "[{\"'":
            raise ValueError(f"cannot read {text!r} as a TOML value ({e})") from None
        return text
    if set(data) != {"v"}:  # a value with a line break that smuggles in more keys
        raise ValueError(f"cannot read {text!r} as one TOML value")
    return data["v"]


def parse_sets(sets: list[str] | None) -> dict[str, Any]:
    """``["render.spp=16", "camera.position=[0,10,0]"]`` → ``{"render.spp": 16, "camera.position": [0, 10, 0]}``.

    A later setting of the same key wins.  A :class:`~forest.errors.ParameterError` naming ``--set`` for
    an item without ``=`` or a key, or a value :func:`parse_value` cannot read.
    """
    import re

    from ..errors import ParameterError

    out: dict[str, Any] = {}
    for item in sets or ():
        key, eq, text = str(item).partition("=")
        key = key.strip()
        if not eq or not key:
            raise ParameterError("--set", f"{item!r}: use KEY.PATH=VALUE, e.g. render.spp=16")
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*(\[\d+\])?(\.[A-Za-z_][A-Za-z0-9_]*(\[\d+\])?)*", key):
            raise ParameterError(f"--set {key}", "not a config key; use a dotted path such as render.spp")
        try:
            out[key] = parse_value(text)
        except ValueError as e:
            raise ParameterError(f"--set {key}", str(e)) from None
    return out


def _owner(field: str | None, labelled: dict[str, str]) -> str | None:
    """The flag (``--set render.spp``) whose key ``field`` is, is inside, or is a table above (None: none)."""
    if not field:
        return None
    for key, label in reversed(labelled.items()):
        if field == key or field.startswith((f"{key}.", f"{key}[")) or key.startswith((f"{field}.", f"{field}[")):
            return label
    return None


def load_with_flags(
    path: Path,
    overrides: dict[str, Any],
    sets: list[str] | None = None,
    *,
    labelled: dict[str, tuple[str, Any]] | None = None,
):
    """Load a config with flag values applied as overrides of their fields (None = not given).

    ``sets``: the ``--set KEY.PATH=VALUE`` items (:func:`parse_sets`), applied first, so a command's own
    flag (``--spp``) wins over ``--set render.spp``; ``labelled``: more overrides, ``{key: (flag, value)}``
    (``forest wedge``), applied after ``sets``.  A bad value from a flag is reported against the flag
    (``--spp``, ``--set render.spp``), with the config validation's own words, not against the file.
    """
    from ..config import ConfigError, load_config
    from ..errors import ForestError, ParameterError

    given = {k: v for k, v in overrides.items() if v is not None}
    flags = {key: (f"--set {key}", value) for key, value in parse_sets(sets).items()}
    flags.update(labelled or {})
    labels = {key: label for key, (label, _) in flags.items()}
    merged = {**{key: value for key, (_, value) in flags.items()}, **given}
    try:
        config = load_config(path, overrides=merged)
    except ConfigError as e:
        if e.field in given:
            raise e.for_parameter(e.field) from None
        label = _owner(e.field, {k: v for k, v in labels.items() if k not in given})
        if label is not None:
            # A field inside the table the flag set (--set render.valley_fog={...}) is named after the flag.
            key, field = label.removeprefix("--set "), e.field or ""
            inside = label.startswith("--set ") and field.startswith(f"{key}.")
            raise ParameterError(label, f"{field[len(key) + 1 :]}: {e.message}" if inside else e.message) from None
        raise
    except ForestError as e:  # apply_overrides: "override 'KEY': species has no element 3"
        for key, label in labels.items():
            lead = f"override {key!r}: "
            if e.message.startswith(lead):
                raise ParameterError(label, e.message[len(lead) :]) from None
        raise
    _refuse_unused_pose(config, labels)
    return config


def _refuse_unused_pose(config: Any, labels: dict[str, str]) -> None:
    """A flag that sets ``camera.position`` or ``camera.target`` of a scene with ``camera.keys`` would change
    nothing (every frame's pose, a still's too, comes from the keys): refused, naming the flag."""
    from ..errors import ParameterError

    keys = config.camera.keys
    for name in ("position", "target"):
        label = labels.get(f"camera.{name}")
        if label is None or not keys:
            continue
        first = tuple(getattr(keys[0], name))
        if any(abs(a - b) > 1e-9 for a, b in zip(getattr(config.camera, name), first)):
            raise ParameterError(
                label,
                f"is not used: [camera] keys set the camera of every frame (keys[0].{name} = {list(first)}); "
                "set the keys (camera.keys[0].position …), or camera.keys=[] for a still camera",
            )
