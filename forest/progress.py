"""Progress of long work on stderr: a rich bar on a terminal, plain ``Progress: N%`` lines elsewhere.

Render farm managers (Deadline, Tractor, OpenCue) read a task's progress from
lines such as ``Progress: 42% render: frame 3 (3/8)`` in its log, so when
stderr is not a terminal forest prints those instead of a bar.  The mode is
chosen by ``forest --progress auto|bar|lines|none`` or the environment variable
:data:`ENV` (``FOREST_PROGRESS``):

* ``auto`` (the default): ``bar`` when stderr is a terminal, ``lines`` otherwise;
* ``bar``: the rich progress bar, even when stderr is not a terminal;
* ``lines``: one line per change of at least one percent or a new message,
  at most one every :data:`LINE_INTERVAL_S` seconds, flushed at once, and
  always a last ``Progress: 100%`` line when the stage finishes;
* ``none``: nothing.

A command's ``-q/--quiet`` silences progress in every mode.  ``forest render``,
``wedge`` and ``match`` also take ``--progress`` after the command
(:func:`command_mode`), where a farm's job template appends its flags; it wins
over the root option.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from collections.abc import Callable, Iterator
from typing import TextIO

ProgressFn = Callable[[float, str], None]  # (fraction in [0, 1], message)

#: The ways progress can be shown (``forest --progress``).
MODES = ("auto", "bar", "lines", "none")
#: The environment variable that chooses the mode when ``--progress`` is not given.
ENV = "FOREST_PROGRESS"
#: Fewest seconds between two progress lines (the first and the last are always printed).
LINE_INTERVAL_S = 1.0

_mode: str | None = None  # set by the command line's --progress


def set_mode(mode: str | None) -> None:
    """Use ``mode`` (one of :data:`MODES`) for the progress of this process; None: :data:`ENV`, else ``auto``."""
    if mode is not None and mode not in MODES:
        raise ValueError(f"progress mode must be one of {', '.join(MODES)}, got {mode!r}")
    global _mode
    _mode = mode


#: The help of a command's own ``--progress`` (:func:`command_mode`).
COMMAND_HELP = (
    "How this command shows its progress on stderr: bar, 'Progress: N%' lines for render farms, none, or auto "
    "(a bar on a terminal, lines otherwise); wins over 'forest --progress'."
)


def command_mode(mode: str | None) -> None:
    """Apply a command's own ``--progress`` (None: not given, the root option or :data:`ENV` stays in effect)."""
    if mode is not None:
        set_mode(mode)


def progress_mode(stream: TextIO | None = None) -> str:
    """The mode in effect for ``stream`` (default stderr): ``bar``, ``lines`` or ``none``.

    :func:`set_mode`'s choice, else :data:`ENV`'s (an unknown value counts as ``auto``), with ``auto``
    resolved: ``bar`` on a terminal, ``lines`` otherwise."""
    mode = _mode or os.environ.get(ENV, "").strip().lower() or "auto"
    if mode not in MODES or mode == "auto":
        out = sys.stderr if stream is None else stream
        try:
            return "bar" if out.isatty() else "lines"
        except (AttributeError, ValueError):  # a closed or odd stream
            return "lines"
    return mode


def _ignore(_fraction: float, _message: str = "") -> None:
    return None


def scaled(progress: ProgressFn | None, start: float, end: float) -> ProgressFn:
    """``progress`` for a step that fills ``start``..``end`` of its caller's work (None: a callback that says nothing).

    A builder reports its own 0..1; the caller's bar moves from ``start`` to ``end``."""
    if progress is None:
        return _ignore
    span = float(end) - float(start)

    def update(fraction: float, message: str = "") -> None:
        progress(float(start) + span * max(0.0, min(1.0, float(fraction))), message)

    return update


def _percent(fraction: float) -> int:
    """Whole percent of ``fraction`` in [0, 1], rounded down (100 only when done); NaN counts as 0."""
    f = float(fraction)
    return int(max(0.0, min(1.0, f if f == f else 0.0)) * 100)


class ProgressLines:
    """Writes ``Progress: N% <stage>: <message>`` lines for one stage (see the module docstring).

    ``clock`` (seconds) and ``interval`` are here for tests."""

    def __init__(
        self,
        stage: str,
        stream: TextIO,
        *,
        interval: float = LINE_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.stage = stage
        self.stream = stream
        self.interval = float(interval)
        self.clock = clock
        self.percent = 0
        self.message = ""
        self.printed: tuple[int, str] | None = None  # (percent, message) of the last line
        self.printed_at = 0.0

    def line(self, percent: int, message: str) -> str:
        """The text of one progress line."""
        what = f"{self.stage}: {message}" if message and self.stage else (message or self.stage)
        return f"Progress: {percent}% {what}".rstrip()

    def _write(self) -> None:
        self.stream.write(self.line(self.percent, self.message) + "\n")
        self.stream.flush()
        self.printed = (self.percent, self.message)
        self.printed_at = self.clock()

    def update(self, fraction: float, message: str = "") -> None:
        """Record the stage's progress; print it when it moved a whole percent or says something new,
        and the last line is at least ``interval`` seconds old (the first line is printed at once)."""
        percent = _percent(fraction)
        message = " ".join(str(message or "").split())
        if percent < self.percent and message == self.message:
            return  # never step back without a reason
        self.percent, self.message = percent, message
        if self.printed is None:
            self._write()
            return
        moved = percent >= self.printed[0] + 1 or message != self.printed[1]
        if moved and self.clock() - self.printed_at >= self.interval:
            self._write()

    def finish(self) -> None:
        """Print the final ``Progress: 100% <stage>: done`` line, unless a line at 100 % was the last."""
        if self.printed is not None and self.printed[0] == 100:
            return
        self.percent, self.message = 100, "done"
        self._write()


@contextlib.contextmanager
def progress_bar(description: str, *, quiet: bool = False) -> Iterator[ProgressFn]:
    """Yield ``update(fraction, message)`` for the work of stage ``description``, shown on stderr.

    As a rich bar or as ``Progress: N%`` lines, or not at all (``quiet``, or mode ``none``), by
    :func:`progress_mode`.  The lines end with ``Progress: 100%`` when the work ends without an error."""
    mode = "none" if quiet else progress_mode()
    if mode == "none":
        yield _ignore
        return
    if mode == "lines":
        lines = ProgressLines(description, sys.stderr, interval=LINE_INTERVAL_S)
        yield lines.update
        lines.finish()
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[msg]}", markup=False),
        console=Console(stderr=True, force_terminal=True if not sys.stderr.isatty() else None),
        transient=True,
    ) as p:
        task = p.add_task(description, total=1.0, msg="")

        def update(fraction: float, message: str = "") -> None:
            p.update(task, completed=max(0.0, min(1.0, fraction)), msg=message)

        yield update
