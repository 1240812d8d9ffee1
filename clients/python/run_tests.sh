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
# The tests run from clients/python: a path relative to the caller's directory must not
# change meaning there.
TRINOCULAR_BIN="$(cd "$(dirname "$TRINOCULAR_BIN")" && pwd)/$(basename "$TRINOCULAR_BIN")"
python3 -m venv "$venv"
"$venv/bin/python" -m pip install -q --upgrade pip build
# The client is built as a wheel (and an sdist, then a wheel from it) outside the source tree,
# and the wheel installed: building must write nothing into clients/python.
tree() { (cd "$here" && find . -path ./.pytest_cache -prune -o -name __pycache__ -prune -o -print | sort); }
before="$(tree)"
dist="$(mktemp -d)"
trap 'rm -rf "$dist"' EXIT
"$venv/bin/python" -m build -q --outdir "$dist" "$here" >/dev/null
if [ "$before" != "$(tree)" ]; then
  echo "building the client wrote into the source tree:" >&2
  diff <(echo "$before") <(tree) >&2
  exit 1
fi
wheel="$(ls "$dist"/trinocular-*.whl)"
"$venv/bin/python" -m pip uninstall -q -y trinocular 2>/dev/null || true
"$venv/bin/python" -m pip install -q "$wheel[rerun]" pytest numpy trustme opencv-python-headless
cd "$here"
"$venv/bin/python" -m pytest -q tests "${@:2}"
