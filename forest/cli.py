"""The ``forest`` command line.

Sub-commands live in :mod:`forest.commands`, one module each; every one calls
the same public functions the service and the tests call.  User mistakes
(:class:`~forest.errors.ForestError`), bad option values and unusable
output paths print one line and exit with status 2; a bug in forest prints
one line saying so and where its traceback was written, and exits with
status 1 (``FOREST_DEBUG=1`` prints the traceback instead).
"""

from __future__ import annotations

import errno
import importlib
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Literal, NoReturn, TextIO

import typer

try:  # typer ≥ 0.17 carries its own copy of click
    from typer._click import exceptions as click_errors
    from typer._click.utils import PacifyFlushWrapper
except ImportError:  # pragma: no cover - older typer on the public click
    from click import exceptions as click_errors  # type: ignore[no-redef]
    from click.utils import PacifyFlushWrapper  # type: ignore[no-redef]

from .errors import ForestError, ForestWarning, ParameterError

app = typer.Typer(
    name="forest",
    help="Grow, render, export and look-dev forests of 100 000 to 1 000 000+ trees.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    # Plain help: ``[render]`` in a help text is a config section, not markup, and flags show no value type.
    rich_markup_mode=None,
    context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 120},
)


def _version(value: bool):
    if value:
        from . import __version__

        typer.echo(f"forest {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    _print_version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
    progress: Literal["auto", "bar", "lines", "none"] = typer.Option(
        "auto",
        "--progress",
        envvar="FOREST_PROGRESS",
        help="How long work shows its progress on stderr: a bar, 'Progress: N%' lines for render farms, or "
        "nothing (auto: a bar on a terminal, lines otherwise). A command's --quiet silences it.",
    ),
):
    """Grow, render, export and look-dev forests of 100 000 to 1 000 000+ trees."""
    from .progress import set_mode

    set_mode(progress)


# Each module defines ``register(app)``.
COMMAND_MODULES = (
    "scatter",
    "render",
    "wedge",
    "library",
    "serve",
    "submit",
    "export",
    "match",
    "examples",
    "schema",
)

for _name in COMMAND_MODULES:
    importlib.import_module(f".commands.{_name}", __package__).register(app)


def fail(message: str, code: int = 2) -> NoReturn:
    """Print one line to stderr and exit (a message with line breaks is folded onto one line)."""
    line = " ".join(part.strip() for part in str(message).splitlines() if part.strip())
    typer.echo(f"forest: error: {line}", err=True)
    raise SystemExit(code)


def _one_line_warnings(show: Callable[..., None]) -> Callable[..., None]:
    """A ``warnings.showwarning`` that prints forest's own warnings as one line and passes others to ``show``."""

    def show_warning(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> None:
        if issubclass(category, ForestWarning):
            typer.echo(f"forest: warning: {message}", err=True)
        else:
            show(message, category, filename, lineno, file, line)

    return show_warning


#: OS errors that are about the user's files or machine (a full disk, a read-only folder), not forest's code.
USER_ERRNOS = frozenset(
    {
        errno.ENOSPC,
        errno.EDQUOT,
        errno.EFBIG,
        errno.EACCES,
        errno.EPERM,
        errno.EROFS,
        errno.EISDIR,
        errno.ENOTDIR,
        errno.EEXIST,
        errno.ENOENT,
        errno.ENAMETOOLONG,
    }
)

#: Set to print a bug's traceback on stderr instead of into a file.
DEBUG_ENV = "FOREST_DEBUG"


def _usage_error(e: click_errors.UsageError) -> str:
    """A command-line usage error (bad option value, missing option, unknown command) as one line."""
    path = e.ctx.command_path if e.ctx is not None else "forest"
    command = path.removeprefix("forest").strip()
    where = f"{command}: " if command else ""
    message = e.format_message().replace(": Value error, ", ": ")  # typer's wording for a value not among the choices
    return f"{where}{message} (see '{path} --help')"


#: Commands whose output is a listing: a reader that stops early (``forest examples list | head``) is no error.
LISTINGS = (("examples", "list"), ("library", "list"), ("schema",))


def _is_listing(args: list[str]) -> bool:
    """Whether ``args`` ask for a listing, help or the version (see :data:`LISTINGS`)."""
    if any(a in ("-h", "--help", "--version", "--show-completion") for a in args):
        return True
    words = [a for a, before in zip(args, ["", *args]) if not a.startswith("-") and before != "--progress"]
    return any(tuple(words[: len(cmd)]) == cmd for cmd in LISTINGS)


def _reader_gone(args: list[str]) -> NoReturn:
    """The reader of our output went away (``| head``): print nothing more and exit, 0 for a listing, else 1."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # the interpreter's last flush of stdout must not fail too
    except (OSError, ValueError):
        pass
    sys.stderr = open(os.devnull, "w")
    raise SystemExit(0 if _is_listing(args) else 1)


def save_traceback(exc: BaseException, argv: list[str]) -> Path | None:
    """Write ``exc``'s traceback (and the command line and version) to a file in the user state folder.

    Returns the file, or None when it could not be written.
    """
    import time
    import traceback

    import platformdirs

    from . import __version__

    folder = platformdirs.user_state_path("forest") / "tracebacks"
    name = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.txt"
    text = f"forest {__version__}, Python {sys.version.split()[0]}\ncommand: forest {' '.join(argv)}\n\n" + "".join(
        traceback.format_exception(exc)
    )
    try:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)
    except OSError:
        return None
    return folder / name


def _bug(exc: BaseException, argv: list[str]) -> NoReturn:
    """forest's own failure: one line saying so and where the traceback is; exit status 1."""
    if os.environ.get(DEBUG_ENV):
        raise exc
    path = save_traceback(exc, argv)
    what = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
    where = f"the traceback is in {path}" if path else f"set {DEBUG_ENV}=1 to see the traceback"
    fail(f"internal error (a bug in forest, not in your input): {what}; {where}", 1)


def main(argv: list[str] | None = None) -> NoReturn:
    """Run the CLI and exit: 0 on success, 2 with one line for a user's mistake, 1 with one line for a bug."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line_warnings(warnings.showwarning)
            code = app(args=args, prog_name="forest", standalone_mode=False)
    except SystemExit:
        if isinstance(sys.stdout, PacifyFlushWrapper):  # typer met a broken pipe (EPIPE), wrapped stdout and exits 1
            _reader_gone(args)
        raise
    except click_errors.NoArgsIsHelpError as e:
        try:
            text = e.ctx.get_help()  # typer's rich help prints itself and returns ""
            if text:
                typer.echo(text)
        except BrokenPipeError:
            _reader_gone(args)
        raise SystemExit(2) from None
    except click_errors.UsageError as e:
        fail(_usage_error(e), 2)
    except click_errors.ClickException as e:
        fail(e.format_message(), e.exit_code)
    except typer.Abort:
        fail("aborted", 1)
    except ParameterError as e:
        from .commands import FLAGS

        fail(f"{FLAGS.get(e.field or '', e.field)}: {e.message}", e.exit_code)
    except ForestError as e:
        fail(str(e), e.exit_code)
    except KeyboardInterrupt:
        fail("interrupted", 130)
    except MemoryError:
        fail("out of memory: render fewer pixels (render.width, render.height) or fewer trees", 2)
    except RuntimeError as e:
        if "out of memory" not in str(e).lower():  # drjit's and Mitsuba's allocators raise RuntimeError
            _bug(e, args)
        fail("out of memory: render fewer pixels (render.width, render.height) or fewer trees", 2)
    except OSError as e:
        if e.errno == errno.EPIPE:  # the reader of our output went away (e.g. `| head`)
            _reader_gone(args)
        if e.errno in USER_ERRNOS:
            name = e.filename if e.filename is not None else ""
            fail(f"{name}: {e.strerror}" if name else str(e.strerror or e), 2)
        _bug(e, args)
    except Exception as e:
        _bug(e, args)
    raise SystemExit(code if isinstance(code, int) else 0)


if __name__ == "__main__":
    main(sys.argv[1:])
