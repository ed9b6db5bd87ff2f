#!/usr/bin/env bash
# One-shot, idempotent set-up of a fresh checkout:
#   * LLVM 19 (drjit's CPU backend; older LLVMs crash in drjit 1.5),
#   * Chromium (the service page tests) and Blender (the Blender export tests), from Debian,
#   * a virtual environment at .venv/ with the exact versions of requirements.lock and forest itself,
#   * the generated tree library (built into the user library's cache: $FOREST_LIBRARY, else
#     the per-user data folder, e.g. ~/.local/share/forest/library/cache/).
# Re-running it is cheap: every step checks whether it is already done.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
PY=${PYTHON:-python3}

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

# --- Blender (forest export blender is tested by rendering its .blend in Cycles) ----
# Debian 12's blender 3.4.1; without recommended packages it installs in about two minutes.
if ! command -v blender >/dev/null; then
    say "installing Blender (Debian package blender)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    if command -v apt-get >/dev/null; then
        $SUDO apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends blender >/dev/null
    fi
    command -v blender >/dev/null || { echo "setup: blender not found and could not be installed" >&2; exit 2; }
fi

# --- virtual environment -----------------------------------------------------
if [ ! -x .venv/bin/python ]; then
    say "creating .venv"
    "$PY" -m venv .venv
fi
STAMP=.venv/.forest-installed
HASH=$(cat pyproject.toml requirements.lock | sha256sum | cut -c1-16)
if [ ! -f "$STAMP" ] || [ "$(cat "$STAMP")" != "$HASH" ]; then
    say "installing requirements.lock and forest into .venv"
    .venv/bin/python -m pip install -q --upgrade pip
    .venv/bin/python -m pip install -q -r requirements.lock
    PYTHONWARNINGS=ignore .venv/bin/python -m pip install -q --no-deps -e .
    echo "$HASH" > "$STAMP"
fi
# Make the venv remember where LLVM is, for every process it starts.
echo "$LLVM" > .venv/llvm-path

# --- tree library --------------------------------------------------------------
say "building the tree library (into the user library's cache)"
.venv/bin/forest library build --quiet
say "ready: .venv/bin/forest"
