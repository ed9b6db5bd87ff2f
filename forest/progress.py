"""Progress bars for long work (rich), quiet when asked or when not on a terminal."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable, Iterator

ProgressFn = Callable[[float, str], None]  # (fraction in [0, 1], message)


@contextlib.contextmanager
def progress_bar(description: str, *, quiet: bool = False) -> Iterator[ProgressFn]:
    """Yield ``update(fraction, message)``; draws a rich progress bar on stderr."""
    if quiet or not sys.stderr.isatty():

        def ignore(_fraction: float, _message: str = "") -> None:
            return None

        yield ignore
        return
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        TextColumn("{task.fields[msg]}"),
        console=Console(stderr=True),
        transient=True,
    ) as p:
        task = p.add_task(description, total=1.0, msg="")

        def update(fraction: float, message: str = "") -> None:
            p.update(task, completed=max(0.0, min(1.0, fraction)), msg=message)

        yield update
