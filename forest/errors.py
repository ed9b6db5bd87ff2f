"""User-facing errors.

Every mistake a user can make (a bad config value, a missing map, a corrupt
image, an unknown species, a bad argument) raises :class:`ForestError` with one
line that names the file and the field, or the parameter.  The CLI prints that
line and exits with status 2; it never shows a traceback for these.

Library code names *parameters*, never command-line flags: a
:class:`ParameterError` carries the parameter's name (``output``, ``frames``,
``lookdev.iterations`` …) in ``field``, and each front end maps it to what its
user typed — the CLI to its flag (``-o``, ``--frames``), the service to its
JSON field.
"""

from __future__ import annotations

from pathlib import Path


class ForestError(Exception):
    """A user mistake: printed as one line, exit status 2.

    ``field`` names the parameter or config field at fault when there is one;
    ``message`` is the line without it.
    """

    exit_code = 2

    def __init__(self, message: str, *, field: str | None = None):
        self.field = field
        self.message = message
        super().__init__(message if field is None else f"{field}: {message}")


class ParameterError(ForestError):
    """A bad value of a function's parameter (a command-line option, a job setting)."""

    def __init__(self, field: str, message: str):
        super().__init__(message, field=field)


class ConfigError(ForestError):
    """A bad value in a config file, reported as ``file: field: message``."""

    def __init__(self, path: str | Path | None, field: str | None, message: str):
        self.path = str(path) if path is not None else None
        self.field = field
        self.message = message
        parts = [p for p in (self.path, field) if p]
        Exception.__init__(self, ": ".join([*parts, message]))

    def for_parameter(self, name: str) -> ParameterError:
        """The same mistake reported against parameter ``name`` (the value came from it, not the file)."""
        return ParameterError(name, self.message)


class ForestWarning(UserWarning):
    """Something a user should know that does not stop the work: the CLI prints it as one line."""
