#!/usr/bin/env python3
"""Regenerate docs/openapi.json, the job service's OpenAPI document, from its FastAPI app.

Run after changing a route or a request or response model:  make openapi
(or .venv/bin/python scripts/make_openapi.py).  tests/test_docs.py fails while the
committed file differs from what the app produces.

The document is the one the service serves at ``/openapi.json``, written with sorted
keys, two-space indents and a trailing newline, so the same code gives the same bytes.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
OUTPUT = ROOT / "docs" / "openapi.json"
sys.path.insert(0, str(ROOT))


def openapi_text() -> str:
    """The service's OpenAPI document as the text docs/openapi.json holds."""
    from forest.service.app import ServiceConfig, create_app

    # create_app lays out a data folder; the document does not depend on where it is
    with tempfile.TemporaryDirectory() as tmp:
        app = create_app(ServiceConfig(data_dir=Path(tmp) / "data", seed_examples=False, dispatch=False))
        document = app.openapi()
    return json.dumps(document, indent=2, sort_keys=True, ensure_ascii=False) + "\n"


def main() -> None:
    from forest.atomic import atomic_path

    with atomic_path(OUTPUT) as tmp:
        tmp.write_text(openapi_text(), encoding="utf-8")
    print(OUTPUT.relative_to(ROOT))


if __name__ == "__main__":
    main()
