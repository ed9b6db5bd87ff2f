"""Mitsuba / drjit runtime set-up: LLVM discovery, variant selection, third-party stderr.

drjit 1.5's CPU backend needs LLVM 19 (LLVM 14–16 crash with
``Cannot select: fminimum``).  :func:`ensure_llvm` finds ``libLLVM-19.so`` and
names it in ``DRJIT_LIBLLVM_PATH`` before mitsuba is imported;
:func:`mitsuba` imports mitsuba with a variant set.

C and C++ libraries (libpng, libjpeg, OpenImageIO, Mitsuba, drjit) print
their own complaints straight to file descriptor 2, around and beside the one
line forest prints for the same mistake.  :func:`captured_stderr` redirects
the descriptor around such a call and hands the text back, so that the caller
can fold it into its own message (or drop it when the library also reported
the error through its API).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from .errors import ForestError, ParameterError

VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")

_LLVM_CANDIDATES = (
    "/usr/lib/x86_64-linux-gnu/libLLVM-19.so",
    "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1",
    "/usr/lib/llvm-19/lib/libLLVM-19.so",
    "/usr/lib/llvm-19/lib/libLLVM.so.1",
    "/usr/lib/aarch64-linux-gnu/libLLVM-19.so",
    "/usr/local/lib/libLLVM-19.so",
)


def find_llvm() -> str | None:
    """Return the path of an LLVM 19 shared library, or None."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and Path(env).is_file():
        return env
    stamp = Path(sys.prefix) / "llvm-path"
    if stamp.is_file():
        p = stamp.read_text().strip()
        if Path(p).is_file():
            return p
    for p in _LLVM_CANDIDATES:
        if Path(p).is_file():
            return p
    return None


def ensure_llvm() -> str:
    """Point drjit at LLVM 19; raise a clear error if it is not installed."""
    path = find_llvm()
    if path is None:
        raise ForestError(
            "LLVM 19 not found: install the Debian package libllvm19 (scripts/setup.sh does) "
            "or set DRJIT_LIBLLVM_PATH to libLLVM-19.so"
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def cuda_available() -> bool:
    """True when an NVIDIA driver is present (cheap check, no CUDA context)."""
    return any(Path(p).exists() for p in ("/dev/nvidia0", "/proc/driver/nvidia/version"))


_current: str | None = None


def mitsuba(variant: str = "scalar_rgb"):
    """Import mitsuba with ``variant`` set; return the module."""
    global _current
    if variant not in VARIANTS:
        raise ParameterError("variant", f"must be one of {', '.join(VARIANTS)}, got {variant!r}")
    if variant.startswith("llvm"):
        ensure_llvm()
    else:
        find = find_llvm()
        if find:
            os.environ.setdefault("DRJIT_LIBLLVM_PATH", find)
    import mitsuba as mi

    if _current != variant:
        try:
            mi.set_variant(variant)
        except Exception as e:
            raise ForestError(f"cannot use Mitsuba variant {variant}: {e}") from None
        _current = variant
    return mi


@contextlib.contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """Redirect file descriptor 2 into a temporary file while the block runs.

    Yields a list that, once the block has ended (normally or not), holds the
    non-empty lines written to descriptor 2 meanwhile — by Python or by any C
    library.  Nested use is fine; output of other threads in the window is
    captured too, so keep the window to the one call that may complain.
    """
    lines: list[str] = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no descriptor 2 (embedded interpreters): nothing to capture
        yield lines
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            with contextlib.suppress(OSError, ValueError):
                sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", "replace")
            lines.extend(line.strip() for line in text.splitlines() if line.strip())
