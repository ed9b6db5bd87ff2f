"""The ``forest`` command line.

Sub-commands live in :mod:`forest.commands`, one module each; every one calls
the same public functions the service and the tests call.  User mistakes
(:class:`~forest.errors.ForestError`) print one line and exit with status 2.
"""

from __future__ import annotations

import importlib
import sys

import typer

from .errors import ForestError, ParameterError

app = typer.Typer(
    name="forest",
    help="Grow, render, export and look-dev forests of 100 000 to 1 000 000+ trees.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool):
    if value:
        from . import __version__

        typer.echo(f"forest {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
):
    """Grow, render, export and look-dev forests of 100 000 to 1 000 000+ trees."""


# Each module defines ``register(app)``.
COMMAND_MODULES = (
    "scatter",
    "render",
    "library",
    "serve",
    "export",
    "match",
    "examples",
)

for _name in COMMAND_MODULES:
    importlib.import_module(f".commands.{_name}", __package__).register(app)


def fail(message: str, code: int = 2) -> None:
    """Print one line to stderr and exit."""
    typer.echo(f"forest: error: {message}", err=True)
    raise SystemExit(code)


#: Library parameters whose command-line flag is not ``--<param>``.
FLAGS = {"output": "-o"}


def flag(param: str) -> str:
    """The command-line flag of a library parameter."""
    return FLAGS.get(param, "--" + param.replace("_", "-"))


def main(argv: list[str] | None = None) -> None:
    try:
        app(args=argv, prog_name="forest")
    except ParameterError as e:
        fail(e.named(flag(e.param)), e.exit_code)
    except ForestError as e:
        fail(str(e), e.exit_code)
    except KeyboardInterrupt:
        fail("interrupted", 130)
    except MemoryError:
        fail("out of memory", 1)


if __name__ == "__main__":
    main(sys.argv[1:])
