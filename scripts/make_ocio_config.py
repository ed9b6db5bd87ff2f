#!/usr/bin/env python3
"""Regenerate forest's OpenColorIO config (forest/imaging/ocio/) from forest/imaging/curves.py.

Run after changing a curve parameter:  .venv/bin/python scripts/make_ocio_config.py
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from forest.imaging.ocio_config import write_config  # noqa: E402

if __name__ == "__main__":
    for path in write_config(ROOT / "forest" / "imaging" / "ocio"):
        print(path.relative_to(ROOT))
