#!/usr/bin/env bash
# Regenerate requirements.lock (the exact versions set-up and CI install) from the
# dependency ranges in pyproject.toml.  Run after changing a range; commit both.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
"$PY" -m pip install -q uv
"$PY" -m uv pip compile pyproject.toml --extra service --extra test --extra ray --extra dev --extra denoise \
    --python-version 3.11 --python-platform x86_64-manylinux_2_28 --no-header --quiet -o requirements.lock
