#!/usr/bin/env bash
# Build prerequisites, then the full test suite (the command the README and CI use).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

bash scripts/setup.sh

if [[ ! -d ../shared ]]; then
    echo "test.sh: ../shared (Zemax reference data) not found; tests that need it will be skipped."
fi

# Unit, integration and CLI tests (the Embree backend included: it is a default feature), benches compiled and
# run once in test mode, then the doc examples.
cargo test --release --all-targets
cargo test --release --doc

# The analytic tracer alone must keep building without Embree (`--no-default-features`).
cargo check --release --no-default-features --lib --bins --tests
