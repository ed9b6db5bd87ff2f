#!/usr/bin/env bash
# One-shot, idempotent set-up of a fresh checkout:
#   * LLVM 19 (drjit's CPU backend; older LLVMs crash in drjit 1.5),
#   * a virtual environment at .venv/ with forest and its pinned dependencies,
#   * the generated tree library (library/cache/).
# Re-running it is cheap: every step checks whether it is already done.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY=${PYTHON:-python3}
EXTRAS=${FOREST_EXTRAS:-service,test,ray}

say() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }

# --- LLVM 19 -----------------------------------------------------------------
find_llvm() {
    for p in "${DRJIT_LIBLLVM_PATH:-}" /usr/lib/llvm-19/lib/libLLVM.so.1 /usr/lib/llvm-19/lib/libLLVM-19.so \
             /usr/lib/x86_64-linux-gnu/libLLVM-19.so /usr/lib/x86_64-linux-gnu/libLLVM-19.so.1 \
             /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1; do
        [ -n "$p" ] && [ -f "$p" ] && { echo "$p"; return 0; }
    done
    return 1
}
if ! LLVM=$(find_llvm); then
    say "installing LLVM 19 (Debian package libllvm19)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    if command -v apt-get >/dev/null; then
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libllvm19 >/dev/null
    fi
    LLVM=$(find_llvm) || { echo "setup: LLVM 19 not found and could not be installed; install libllvm19 and set DRJIT_LIBLLVM_PATH" >&2; exit 2; }
fi
say "LLVM 19: $LLVM"

# --- Chromium + chromedriver (the job service's page tests drive a headless browser) ----
if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then
    say "installing Chromium and chromedriver (Debian packages chromium, chromium-driver)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    if command -v apt-get >/dev/null; then
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium chromium-driver >/dev/null
    fi
    command -v chromedriver >/dev/null || { echo "setup: chromium-driver not found and could not be installed" >&2; exit 2; }
fi

# --- virtual environment -----------------------------------------------------
if [ ! -x .venv/bin/python ]; then
    say "creating .venv"
    "$PY" -m venv .venv
fi
STAMP=.venv/.forest-installed
HASH=$(cat pyproject.toml | sha256sum | cut -c1-16)-$EXTRAS
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$HASH" ]; then
    say "installing forest[$EXTRAS] into .venv"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -e ".[$EXTRAS]"
    echo "$HASH" > "$STAMP"
fi
# Make the venv remember where LLVM is, for every process it starts.
echo "$LLVM" > .venv/llvm-path

# --- tree library --------------------------------------------------------------
if [ -f forest/library/__init__.py ] || [ -f forest/library.py ]; then
    say "building the tree library (cached under library/cache/)"
    .venv/bin/forest library build --quiet
fi
say "ready: .venv/bin/forest"
