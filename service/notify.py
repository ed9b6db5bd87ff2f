"""In-process notifications: the store announces new events, Server-Sent-Event streams wait for them.

The store calls :meth:`Notifier.publish` after each transaction that appended events
(from whatever thread wrote them); every stream subscribed to one of those jobs has its
``asyncio.Event`` set on its own loop.  A stream therefore sleeps until something
happens instead of polling SQLite, and one write wakes every stream of that job.

The protocol that loses no wake-up: clear the event, read the store, and only then
wait — a publish between the read and the wait leaves the event set.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Iterable, Iterator

ALL = "*"


class Notifier:
    """Thread-safe fan-out from store writes to asyncio waiters, keyed by job id (or :data:`ALL`)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._waiters: dict[str, set[tuple[asyncio.AbstractEventLoop, asyncio.Event]]] = {}

    def publish(self, job_ids: Iterable[str]) -> None:
        """Wake every stream subscribed to one of ``job_ids`` or to :data:`ALL` (callable from any thread)."""
        targets: list[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = []
        with self._lock:
            for key in (*job_ids, ALL):
                targets.extend(self._waiters.get(key, ()))
        for loop, event in targets:
            with contextlib.suppress(RuntimeError):  # the loop closed: its stream is gone
                loop.call_soon_threadsafe(event.set)

    @contextlib.contextmanager
    def subscribe(self, job_id: str) -> Iterator[asyncio.Event]:
        """An event set whenever ``job_id`` gets new events (call from a running loop)."""
        entry = (asyncio.get_running_loop(), asyncio.Event())
        with self._lock:
            self._waiters.setdefault(job_id, set()).add(entry)
        try:
            yield entry[1]
        finally:
            with self._lock:
                waiters = self._waiters.get(job_id)
                if waiters is not None:
                    waiters.discard(entry)
                    if not waiters:
                        del self._waiters[job_id]

    def subscribers(self) -> int:
        """Number of subscriptions open (event streams)."""
        with self._lock:
            return sum(len(w) for w in self._waiters.values())
