#!/usr/bin/env bash
# Build prerequisites, then the full test suite (the command the README and CI use).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."

# Each stage's wall time, printed at the end (also after a failure), so that any log shows where the time goes.
STAGE_TIMES=()
stage() {
    local name=$1 start=$SECONDS
    shift
    "$@"
    STAGE_TIMES+=("$(printf '%6d s  %s' $((SECONDS - start)) "$name")")
}
report_times() {
    local rc=$?
    ((${#STAGE_TIMES[@]} > 0)) && printf 'test.sh: stage times (total %d s%s):\n' "$SECONDS" "$( ((rc == 0)) || echo ", failed")" \
        && printf '  %s\n' "${STAGE_TIMES[@]}"
    return $rc
}
trap report_times EXIT

stage setup bash scripts/setup.sh

if [[ ! -d ../shared ]]; then
    echo "test.sh: ../shared (Zemax reference data) not found; tests that need it will be skipped."
fi

# Unit, integration and CLI tests (the Embree backend included: it is a default feature), benches compiled and
# run once in test mode, then the doc examples.
stage 'cargo test (build and run)' cargo test --release --all-targets
stage 'doc tests' cargo test --release --doc
# One compiled library for every member's build (crates/workspace-hack/Cargo.toml): fails if a dependency's
# features drifted apart between the selections below.
stage 'feature unity' bash scripts/check_feature_unity.sh

# The GPU kernels' device build (docs/gpu.md): NVRTC compiles src/gpu/kernels to PTX, ptxas assembles it for
# sm_90 and prints registers and spills; fails if the committed src/gpu/kernels/trace.ptx is stale. No GPU needed
# (prints SKIP without the NVRTC/ptxas wheels, i.e. with DIFFCASSI_TORCH=skip).
if [[ -x .venv/bin/python ]]; then
    stage 'PTX build' .venv/bin/python scripts/gpu/build_ptx.py
else
    echo "SKIP build_ptx: no .venv (DIFFCASSI_PYTHON=skip)"
fi

# The real Slurm test (docs/slurm.md): a one-node Slurm cluster in a private network namespace renders a job
# array, one task killed and resubmitted; prints SKIP (exit 0) where it cannot run (not root, no namespaces).
stage slurm bash tests/slurm/run.sh

# The analytic tracer alone must keep building without Embree (`--no-default-features`).
stage 'check without Embree' cargo check --release --no-default-features --lib --bins --tests

# The C++ API (cpp/, docs/cpp.md): the bridge crate's Rust tests, then the CMake build
# of the static and shared libraries, the example, the C++ tests and the bench, all run by ctest.
stage 'C++ bridge tests' cargo test --release -p diffcassi-cpp
export CTEST_OUTPUT_ON_FAILURE=1 CMAKE_BUILD_PARALLEL_LEVEL="${CMAKE_BUILD_PARALLEL_LEVEL:-2}"
# (One command per line: under `set -e` a failure inside an `a && b && c` list would not stop the script.)
stage 'C++ configure' cmake -S cpp -B build-cpp
stage 'C++ build' cmake --build build-cpp
stage ctest ctest --test-dir build-cpp
# The build refreshes the generated header in cpp/include; a difference from the committed copy means the
# committed header is stale.
if git rev-parse --is-inside-work-tree >/dev/null 2>&1 && ! git diff --quiet -- cpp/include; then
    git diff --stat -- cpp/include
    echo "test.sh: cpp/include is stale: the build regenerated the cxx bridge header; commit it" >&2
    exit 1
fi

# The Python package (docs/python.md): built into the repository's venv (.venv/, made by setup.sh) with
# maturin from the same cargo target directory, then its pytest suite (tests/python/). DIFFCASSI_PYTHON=skip
# leaves it out; without torch (DIFFCASSI_TORCH=skip) the torch tests report SKIP.
if [[ "${DIFFCASSI_PYTHON:-install}" != skip ]]; then
    stage maturin env VIRTUAL_ENV="$PWD/.venv" PATH="$PWD/.venv/bin:$PATH" .venv/bin/maturin develop --release --quiet
    stage pytest .venv/bin/python -m pytest -q --durations=10 tests/python
    # The installable wheel (docs/python.md, "Installing the wheel"): scripts/build_wheel.sh → dist/, installed
    # with `pip install --no-deps` into a fresh venv; its quickstart must equal the one of the package above.
    stage wheel bash tests/wheel/run.sh
fi
