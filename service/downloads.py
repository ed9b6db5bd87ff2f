"""Downloads of many outputs at once: zip archives built on demand and kept until the outputs change.

An archive is named by the hash of what goes in (each file's job-relative path, size
and modification time), so asking again costs nothing and a re-rendered frame makes a
new one.  Entries carry a fixed time stamp, so the same files give the same archive
bytes; images and USD crates are stored as they are (already compressed), text such as
RIB is deflated.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from pathlib import Path

from .models import digest

STORED = (".exr", ".png", ".jpg", ".jpeg", ".usdc", ".usdz", ".zip", ".npz")
CACHE = ".downloads"
KEEP = 8  # archives kept per job


def collect(job_dir: Path, folder: str = "out", ext: str | None = None) -> list[str]:
    """Job-relative files under ``folder`` (optionally only ``.ext``), sorted."""
    root = job_dir / folder
    if not root.is_dir():
        return []
    out = []
    for p in root.rglob("*"):
        if p.is_file() and not p.name.startswith(".") and (ext is None or p.suffix.lower() == f".{ext}"):
            out.append(p.relative_to(job_dir).as_posix())
    return sorted(out)


def archive(job_dir: Path, files: list[str], base: str) -> Path:
    """A zip of ``files`` (job-relative) with names relative to ``base``; cached in the job folder."""
    stats = []
    for rel in files:
        st = (job_dir / rel).stat()
        stats.append((rel, st.st_size, st.st_mtime_ns))
    cache = job_dir / CACHE
    cache.mkdir(exist_ok=True)
    target = cache / f"{digest({'files': stats, 'base': base})[:24]}.zip"
    if target.is_file():
        os.utime(target)
        return target
    fd, tmp = tempfile.mkstemp(dir=cache, prefix=".zip.", suffix=".tmp")
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", allowZip64=True) as z:
            for rel, *_ in stats:
                name = os.path.relpath(rel, base) if base else rel
                info = zipfile.ZipInfo(name, date_time=(2000, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_STORED if rel.lower().endswith(STORED) else zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                with open(job_dir / rel, "rb") as src, z.open(info, "w", force_zip64=True) as dst:
                    while chunk := src.read(1 << 20):
                        dst.write(chunk)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    old = sorted((p for p in cache.glob("*.zip")), key=lambda p: p.stat().st_mtime)
    for p in old[: max(0, len(old) - KEEP)]:
        p.unlink(missing_ok=True)
    return target
