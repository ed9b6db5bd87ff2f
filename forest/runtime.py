"""Mitsuba / drjit runtime set-up: LLVM discovery, the GPU, variant selection, third-party stderr.

drjit 1.5's CPU backend needs LLVM 17 or newer (LLVM 14–16 crash with
``Cannot select: fminimum``); forest is set up and tested with LLVM 19, and
LLVM 17 rendered forest_path's demo probe to the same image as the GPU (an
H100 machine whose image had LLVM 16 and 17).  :func:`ensure_llvm` finds
``libLLVM-19.so`` (else 18, else 17) and names it in ``DRJIT_LIBLLVM_PATH``
before mitsuba is imported;
:func:`mitsuba` imports mitsuba with a variant set.  :func:`cuda_available` and
:func:`gpu_info` say whether there is a GPU and which, without starting CUDA
(whether forest_path renders correctly on it is :mod:`forest.render.selfcheck`'s
question).

C and C++ libraries (libpng, libjpeg, OpenImageIO, Mitsuba, drjit) print
their own complaints straight to file descriptor 2, around and beside the one
line forest prints for the same mistake.  :func:`captured_stderr` redirects
the descriptor around such a call and hands the text back, so that the caller
can fold it into its own message (or drop it when the library also reported
the error through its API).
"""

from __future__ import annotations

import contextlib
import functools
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from .errors import ForestError, ParameterError

VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")

#: LLVM versions drjit's CPU backend is given, best first (14–16 crash: see the module docstring).
LLVM_VERSIONS = (19, 18, 17)


def _llvm_candidates(version: int) -> tuple[str, ...]:
    v = int(version)
    return (
        f"/usr/lib/x86_64-linux-gnu/libLLVM-{v}.so",
        f"/usr/lib/x86_64-linux-gnu/libLLVM.so.{v}.1",
        f"/usr/lib/llvm-{v}/lib/libLLVM-{v}.so",
        f"/usr/lib/llvm-{v}/lib/libLLVM.so.1",
        f"/usr/lib/aarch64-linux-gnu/libLLVM-{v}.so",
        f"/usr/local/lib/libLLVM-{v}.so",
    )


_LLVM_CANDIDATES = tuple(p for v in LLVM_VERSIONS for p in _llvm_candidates(v))


def find_llvm() -> str | None:
    """Return the path of an LLVM shared library for drjit (19, else 18, else 17), or None."""
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
    """Point drjit at LLVM 19 (else 18, else 17); raise a clear error if none is installed."""
    path = find_llvm()
    if path is None:
        raise ForestError(
            "LLVM 19 not found (nor 18 or 17): install the Debian package libllvm19 (scripts/setup.sh does) "
            "or set DRJIT_LIBLLVM_PATH to libLLVM-19.so"
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


#: ``CUDA_VISIBLE_DEVICES`` values (its first entry) that hide every GPU from CUDA: empty (what a scheduler sets
#: for work given no GPU, as :class:`forest.service.executors.ray.RayWorker` does), ``-1`` (CUDA stops at the first
#: invalid entry) and ``NoDevFiles`` (Slurm).
HIDDEN_DEVICES = ("", "-1", "NoDevFiles")


def visible_devices() -> str | None:
    """``CUDA_VISIBLE_DEVICES``'s first entry (a GPU index or UUID), ``""`` when it hides every GPU, None when unset."""
    value = os.environ.get("CUDA_VISIBLE_DEVICES")
    if value is None:
        return None
    first = value.split(",")[0].strip()
    return "" if first in HIDDEN_DEVICES else first


def nvidia_driver() -> bool:
    """True when an NVIDIA driver is loaded (its device file or its ``/proc`` entry exists)."""
    return any(Path(p).exists() for p in ("/dev/nvidia0", "/proc/driver/nvidia/version"))


def cuda_available() -> bool:
    """True when an NVIDIA driver is present and ``CUDA_VISIBLE_DEVICES`` does not hide every GPU (cheap check, no
    CUDA context)."""
    return visible_devices() != "" and nvidia_driver()


@dataclass(frozen=True)
class GpuInfo:
    """The GPU this process would render on: its name, memory (MiB) and driver version (None where not known)."""

    name: str
    memory_mib: int | None
    driver: str | None


#: What :func:`gpu_info` names a GPU that ``nvidia-smi`` could not describe.
UNKNOWN_GPU = "NVIDIA GPU (nvidia-smi not found)"
_NVIDIA_SMI_QUERY = ("--query-gpu=name,memory.total,driver_version", "--format=csv,noheader,nounits")


def gpu_info() -> GpuInfo | None:
    """The first GPU ``CUDA_VISIBLE_DEVICES`` leaves visible, from ``nvidia-smi`` (kept for the process); without
    ``nvidia-smi``, a GPU of unknown name and memory with the driver version of ``/proc/driver/nvidia/version``.
    None when :func:`cuda_available` is False.  Never starts CUDA."""
    if not cuda_available():
        return None
    return _gpu_info(visible_devices())


@functools.lru_cache(maxsize=4)
def _gpu_info(device: str | None) -> GpuInfo:
    for args in ([*_NVIDIA_SMI_QUERY, "-i", device], list(_NVIDIA_SMI_QUERY)) if device else [list(_NVIDIA_SMI_QUERY)]:
        try:
            run = subprocess.run(["nvidia-smi", *args], capture_output=True, text=True, timeout=15)
        except (OSError, subprocess.SubprocessError):
            break  # not installed, or hung: /proc below
        lines = [line for line in run.stdout.splitlines() if line.strip()]
        if run.returncode == 0 and lines:
            fields = [f.strip() for f in lines[0].rsplit(",", 2)]
            if len(fields) == 3 and fields[0]:
                memory = int(fields[1]) if fields[1].isdigit() else None
                return GpuInfo(fields[0], memory, fields[2] or None)
    try:
        driver = proc_driver_version(Path("/proc/driver/nvidia/version").read_text(errors="replace"))
    except OSError:
        driver = None
    return GpuInfo(UNKNOWN_GPU, None, driver)


def proc_driver_version(text: str) -> str | None:
    """The driver version in the text of ``/proc/driver/nvidia/version`` (proprietary or open kernel module)."""
    match = re.search(r"Kernel Module(?:\s+for\s+\S+)?\s+(\d+(?:\.\d+)+)", text)
    return match.group(1) if match else None


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


#: Whether Mitsuba builds a scene's objects on its thread pool (``load_dict(..., parallel=...)``).  It
#: does not pay: the objects of a forest's scene are thousands of small instances, and the threads
#: contend for drjit's lock.  20 000 instances of a cube (``bench/bench_gpu.py --cases instances``) took
#: 38 µs each in parallel and 27 serially on 2 CPU cores, 169 and 47 on 16; the fly-through's 130 000
#: trees (about 69 000 instances) on an NVIDIA H200 in ``cuda_ad_rgb`` loaded in about 31 s in parallel and
#: 13.6 s serially (``bench/bench_scene_load.py`` measures it on the machine at hand).
PARALLEL_LOAD = False


def load_scene_dict(mi, entries: dict):
    """``mi.load_dict(entries)`` for a whole scene, built serially (see :data:`PARALLEL_LOAD`)."""
    return mi.load_dict(entries, parallel=PARALLEL_LOAD)


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
