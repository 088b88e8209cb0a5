#!/usr/bin/env bash
# The installable wheel (issue 41, docs/python.md "Installing the wheel"): build it with scripts/build_wheel.sh
# (profile wheel-check, → target/wheel-check-dist/), install it with `pip install --no-deps` into a fresh venv that holds numpy only (no Rust, no
# repository on its path), import it, run examples/python/quickstart.py there and check that its acquisition and
# reconstruction are bit-identical to the same quickstart run with the package `maturin develop` built into .venv
# (what `pip install .` installs), and that the wheel (built without Embree) refuses an Embree backend clearly.
# Needs .venv with the package installed (scripts/test.sh does that just before) and network to PyPI or pip's
# cache for numpy. Prints SKIP (exit 0) with DIFFCASSI_PYTHON=skip or DIFFCASSI_WHEEL=skip (the wheel is a
# cross build that shares nothing with the test build: the first one compiles everything again).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
if [[ "${DIFFCASSI_PYTHON:-install}" == skip || ! -x .venv/bin/python ]]; then
    echo "SKIP tests/wheel: no .venv (DIFFCASSI_PYTHON=skip)"
    exit 0
fi
if [[ "${DIFFCASSI_WHEEL:-build}" == skip ]]; then
    echo "SKIP tests/wheel: DIFFCASSI_WHEEL=skip"
    exit 0
fi
start=$SECONDS
fail() { echo "tests/wheel: FAILED: $*" >&2; exit 1; }

# The workspace at opt-level 1, its dependencies at 0 (Cargo.toml `wheel-check`): the same packaging and results in less cold
# build time. Built into target/wheel-check-dist, not dist/: dist/ keeps the release wheels that
# scripts/gpu_check.sh and scripts/gpu/train_run.sh carry.
bash scripts/build_wheel.sh --profile wheel-check --out target/wheel-check-dist
whl=$(ls target/wheel-check-dist/diffcassi-*.whl)
built=$SECONDS

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
py=python3
[[ -x /usr/bin/python3 ]] && py=/usr/bin/python3
"$py" -m venv "$tmp/venv"
numpy_version=$(.venv/bin/python -c "import numpy; print(numpy.__version__)")
"$tmp/venv/bin/pip" install -q --disable-pip-version-check "numpy==$numpy_version" || fail "pip install numpy==$numpy_version into the fresh venv"
"$tmp/venv/bin/pip" install -q --disable-pip-version-check --no-deps "$whl" || fail "pip install --no-deps $whl"
# Run from a folder outside the repository (the repository root holds a diffcassi/ folder too).
wheel_json=$(cd "$tmp" && "$tmp/venv/bin/python" "$OLDPWD/tests/wheel/quickstart_digest.py" --embree-refusal) || fail "the quickstart from the wheel"
dev_json=$(cd "$tmp" && "$OLDPWD/.venv/bin/python" "$OLDPWD/tests/wheel/quickstart_digest.py") || fail "the quickstart from .venv"
.venv/bin/python - "$wheel_json" "$dev_json" "$tmp/venv" <<'PY' || fail "the wheel's quickstart differs from .venv's (above)"
import json, pathlib, sys
wheel, dev, venv = json.loads(sys.argv[1]), json.loads(sys.argv[2]), pathlib.Path(sys.argv[3]).resolve()
print("tests/wheel: wheel:", wheel["package"], wheel["native"], "embree", wheel["embree"], "|", wheel["quickstart_output"][-1])
print("tests/wheel: .venv:", dev["package"], dev["native"], "embree", dev["embree"])
assert pathlib.Path(wheel["package"]).is_relative_to(venv), f"the fresh venv imported {wheel['package']}, not its own install"
assert not pathlib.Path(dev["package"]).is_relative_to(venv)
assert wheel["native"] == "_native.abi3.so" and not wheel["embree"], wheel
assert wheel["version"] == dev["version"], (wheel["version"], dev["version"])
for k in ("acquisition_sha256", "estimate_sha256", "quickstart_output"):
    assert wheel[k] == dev[k], f"{k}: wheel {wheel[k]} != .venv {dev[k]}"
print(f"tests/wheel: acquisition (total {wheel['acquisition_total']!r}) and reconstruction bit-identical; "
      f"Embree refused: {wheel['embree_refusal'][:80]}…")
PY
echo "tests/wheel: passed (wheel built in $((built - start)) s, installed and compared in $((SECONDS - built)) s)"
