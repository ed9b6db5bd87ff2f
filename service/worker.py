"""A local worker process: runs exactly one task attempt, then exits.

Started by :class:`forest.service.executors.LocalExecutor` as ``python -m forest.service.worker FD``:

* reads one JSON line from stdin: ``{"task_id", "attempt", "spec", "heartbeat_s", "nice"}``;
* writes JSON-line reports to file descriptor ``FD``: ``heartbeat`` every
  ``heartbeat_s`` seconds from a thread (the lease), ``progress`` and ``log`` from the
  render loop, and finally exactly one ``done`` (with the result) or ``error``;
* exits at once when stdin reaches end-of-file: the service that started it is gone,
  so the lease is void and the work would be redone anyway.

stdout and stderr go to the job's log file.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
import traceback


class Channel:
    """Serialised JSON-line writes to the report pipe."""

    def __init__(self, fd: int, task_id: int, attempt: int):
        self.f = os.fdopen(fd, "w", buffering=1, encoding="utf-8")
        self.lock = threading.Lock()
        self.base = {"task_id": task_id, "attempt": attempt}

    def send(self, type_: str, payload: dict | None = None) -> None:
        line = json.dumps({**self.base, "type": type_, **(payload or {})}, separators=(",", ":"))
        with self.lock:
            try:
                self.f.write(line + "\n")
                self.f.flush()
            except (BrokenPipeError, OSError, ValueError):
                os._exit(75)  # the service is gone


def _watch_stdin() -> None:
    try:
        while sys.stdin.buffer.read(1):
            pass
    except OSError:
        pass
    os._exit(75)


def main(argv: list[str]) -> int:
    fd = int(argv[0])
    msg = json.loads(sys.stdin.readline())
    task_id, attempt, spec = msg["task_id"], msg["attempt"], msg["spec"]
    if msg.get("nice"):
        try:
            os.nice(int(msg["nice"]))
        except OSError:
            pass
    chan = Channel(fd, task_id, attempt)
    threading.Thread(target=_watch_stdin, daemon=True).start()
    period = float(msg.get("heartbeat_s", 1.0))

    def beat() -> None:
        while True:
            chan.send("heartbeat")
            time.sleep(period)

    threading.Thread(target=beat, daemon=True).start()
    tag = f"[task {spec.get('index', 0)} attempt {attempt} pid {os.getpid()}]"

    def report(kind: str, payload: dict) -> None:
        if kind == "log":
            print(f"{tag} {payload.get('line', '')}", file=sys.stderr, flush=True)
        elif kind == "progress" and payload.get("message"):
            print(f"{tag} {payload['fraction'] * 100:5.1f}% {payload['message']}", file=sys.stderr, flush=True)
        chan.send(kind, payload)

    from forest.errors import ForestError
    from forest.service.runner import execute

    try:
        result = execute(spec, report)
    except ForestError as e:
        print(f"{tag} error: {e}", file=sys.stderr, flush=True)
        chan.send("error", {"error": str(e), "user": True})
        return 0
    except BaseException as e:
        traceback.print_exc()
        chan.send("error", {"error": f"{type(e).__name__}: {e}", "user": False})
        return 1
    print(f"{tag} done: {len(result.get('outputs', []))} files", file=sys.stderr, flush=True)
    chan.send("done", {"result": result})
    return 0


if __name__ == "__main__":
    code = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # do not wait on the heartbeat thread or renderer thread pools
