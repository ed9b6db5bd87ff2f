"""User-facing errors.

Every mistake a user can make (a bad config value, a missing map, a corrupt
image, an unknown species) raises :class:`ForestError` with one line that names
the file and the field.  The CLI prints that line and exits with status 2; it
never shows a traceback for these.
"""

from __future__ import annotations

from pathlib import Path


class ForestError(Exception):
    """A user mistake: printed as one line, exit status 2."""

    exit_code = 2


class ConfigError(ForestError):
    """A bad value in a config file, reported as ``file: field: message``."""

    def __init__(self, path: str | Path | None, field: str | None, message: str):
        self.path = str(path) if path is not None else None
        self.field = field
        self.message = message
        parts = [p for p in (self.path, field) if p]
        super().__init__(": ".join(parts + [message]))


class ParameterError(ForestError):
    """A bad argument of a library function, named by its parameter (``frames``, ``variant``, …).

    Library code names the parameter, never a front end's spelling of it: the CLI
    shows it as its flag (``--frames: …``), the job service as the request's JSON
    field (``settings.frames: …``), each through :meth:`named`.
    """

    def __init__(self, param: str, message: str):
        self.param = param
        self.message = message
        super().__init__(f"{param}: {message}")

    def named(self, name: str) -> str:
        """The message with the parameter shown as ``name``."""
        return f"{name}: {self.message}"
