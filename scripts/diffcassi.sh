#!/usr/bin/env bash
# Run the diffcassi CLI from a fresh checkout: install what the build needs (scripts/setup.sh), build in
# release mode, and pass every argument through. Example (the README's main job: a coded acquisition of the
# synthetic demo scene through SP, written to out/render-sp):
#   bash scripts/diffcassi.sh render --preset sp
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# The CLI needs no Python: the venv (torch included) is for the test command and the Python package.
DIFFCASSI_PYTHON="${DIFFCASSI_PYTHON:-skip}" bash scripts/setup.sh
exec cargo run --quiet --release --bin diffcassi -- "$@"
