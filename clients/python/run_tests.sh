#!/usr/bin/env bash
# Installs the client in a fresh venv and runs its tests against a live server.
# Usage (from the repo root, after `cargo build --release`):
#   clients/python/run_tests.sh [VENV_DIR]        (default /tmp/trinocular-py-venv)
# The server binary is $TRINOCULAR_BIN, default target/release/trinocular (or
# $CARGO_TARGET_DIR/release/trinocular when CARGO_TARGET_DIR is set).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
root="$(cd "$here/../.." && pwd)"
venv="${1:-/tmp/trinocular-py-venv}"
if [ -z "${TRINOCULAR_BIN:-}" ]; then
  TRINOCULAR_BIN="${CARGO_TARGET_DIR:-$root/target}/release/trinocular"
fi
export TRINOCULAR_BIN
[ -x "$TRINOCULAR_BIN" ] || { echo "no server binary at $TRINOCULAR_BIN (cargo build --release)" >&2; exit 1; }
python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip
"$venv/bin/python" -m pip install -q "$root/clients/python[rerun]" pytest numpy trustme opencv-python-headless
cd "$here"
exec "$venv/bin/python" -m pytest -q tests "${@:2}"
