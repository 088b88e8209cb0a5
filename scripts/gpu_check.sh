#!/usr/bin/env bash
# The GPU check of issue 41 (docs/gpu.md), run on a GPU machine from the wheel and nothing else (no Rust, no
# network; the machine's Python with numpy and torch):
#
#     bash scripts/gpu_check.sh [WHEEL]        # default: the newest dist/diffcassi-*.whl
#
# Installs the wheel with `pip install --no-deps --no-index --target` into a throwaway folder put first on
# PYTHONPATH — not into a venv: the GPU machine's python3 is itself a venv (/opt/torch/.venv), and a venv made
# from a venv sees the *base* interpreter's packages, not the torch and numpy of the one it was made from —,
# checks that `import diffcassi` is the wheel's, prints the GPU, then runs
#   scripts/gpu/render_check.py  — the paper-scale acquisition on the GPU (twice), the CPU and the host twin,
#                                  the middle plane's landings on both;
#   scripts/gpu/render_check.py --systems — the same checks on small renders of a grating (gsp), a toroid lens,
#                                  an object at infinity and SP with real ray aiming (≈ 1 minute);
#   scripts/gpu/torch_check.py   — the exact operator and the torch modules on CUDA tensors (if present);
# prints their tables and writes their JSON records to $OUT (or gpu_out/). Exits non-zero if any check fails.
# DRY_RUN=1: the same script on a machine without a GPU (scripts/gpu/prepare.sh runs it before a GPU machine is
# used): no nvidia-smi or nvcc, the host twin stands in for the device (render_check.py --dry-run) on small renders
# (DRY_SIZE, default 32: 4 planes, 2 rays), torch_check.py --cpu at tiny sizes; the tables say DRY RUN and no
# figure is a GPU's. PYTHON names the interpreter (default python3; a venv is fine, as on the GPU machine).
# Budget: CHECK_BUDGET_S seconds in all (default 400; scripts/gpu/session.sh gives it 20 s under its own cap, and the
# issue's 8 minutes): each step is capped at its own limit (render 300 s, --systems 150 s, torch 240 s) and at
# what is left of the budget, so the caps can never add up past it (they summed to 810 s); a step with under
# 20 s left is not started and counts as a failure. The host twin dominates on few cores (RENDER_ARGS=--no-twin
# skips it); the --systems step is four 128² renders and their twins, ≈ 1 minute.
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
wheel="${1:-$(ls -t "$root"/dist/diffcassi-*.whl 2>/dev/null | head -1)}"
if [[ -z "$wheel" || ! -f "$wheel" ]]; then
    echo "gpu_check: no wheel given and none in dist/ (build one with scripts/build_wheel.sh)" >&2
    exit 2
fi
wheel="$(cd "$(dirname "$wheel")" && pwd)/$(basename "$wheel")"
out="${OUT:-$root/gpu_out}"
mkdir -p "$out"
out="$(cd "$out" && pwd)"
py="${PYTHON:-python3}"
dry="${DRY_RUN:-0}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
"$py" -m pip install -q --disable-pip-version-check --no-deps --no-index --target "$work/site" "$wheel" \
    || { echo "gpu_check: pip could not install $wheel into $work/site" >&2; exit 2; }
export PYTHONPATH="$work/site${PYTHONPATH:+:$PYTHONPATH}"
vpy="$py"
# Run from an empty folder, so that `import diffcassi` is the wheel's and not a source tree's; say so, and what
# numpy and torch are.
cd "$work"
"$vpy" - "$work/site" <<'PY' || { echo "gpu_check: the wheel's diffcassi does not import (above)" >&2; exit 2; }
import os, sys
import numpy
import diffcassi
site = os.path.realpath(sys.argv[1])
assert os.path.realpath(diffcassi.__file__).startswith(site + os.sep), f"imported {diffcassi.__file__}, not the wheel's in {site}"
try:
    import torch
    t = f"torch {torch.__version__}, CUDA {'available' if torch.cuda.is_available() else 'not available'}"
except Exception as e:  # torch_check.py needs it; the render checks do not
    t = f"no torch ({e})"
print(f"gpu_check: diffcassi {diffcassi.__version__} (the wheel's), numpy {numpy.__version__}, {t}, Python {sys.version.split()[0]} at {sys.executable}")
PY
echo "gpu_check: $(basename "$wheel"); $(date -u +%FT%TZ)$([[ "$dry" == 1 ]] && echo "; DRY RUN: no GPU, the host twin stands in for it")"
if [[ "$dry" == 1 ]]; then
    echo "dry run: no GPU" | tee "$out/gpu.txt"
    s="${DRY_SIZE:-32}"
    render_args=(--dry-run --size "$s" --planes 4 --rays 2)
    systems_args=(--dry-run --size "$s" --planes 4 --rays 2)
    torch_args=(--cpu --size 16 --bands 4 --planes 4 --unrolled-size 8 --renderer-size 8 --inference-size 8 --inference-planes 4
        --inference-rays 1 --reps 3 --threads 1)
else
    nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | tee "$out/gpu.txt"
    render_args=()
    systems_args=()
    torch_args=()
    # The embedded PTX is NVRTC 13.0's (ISA 9.0), which a CUDA 13.0 driver (the GPU machine's 580.159) takes. A driver
    # older than that refuses it: the launcher then reads DIFFCASSI_PTX, built here with the machine's own nvcc from
    # the kernel source the wheel carries, then tries the machine's NVRTC, which it looks up on the loader path:
    # torch's pip copy (nvidia/cu13/lib) is on none, so its folder is added.
    nvrtc_dir="$("$vpy" -c 'import glob, os, nvidia; print(next((os.path.dirname(p) for d in nvidia.__path__ for p in sorted(glob.glob(os.path.join(d, "cu*", "lib", "libnvrtc.so.*")))), ""))' 2>/dev/null)"
    if [[ -n "$nvrtc_dir" ]]; then
        export LD_LIBRARY_PATH="${LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}$nvrtc_dir"
    fi
    if [[ -n "${DIFFCASSI_PTX:-}" ]]; then
        echo "gpu_check: DIFFCASSI_PTX=$DIFFCASSI_PTX given: the launcher's fallback after the embedded PTX"
    elif command -v nvcc >/dev/null 2>&1; then
        if "$vpy" -c 'import diffcassi._native as n; print(n._gpu_kernel_source())' > "$work/kernels.cu" \
            && nvcc -ptx -arch=compute_90 --fmad=false -o "$work/kernels.ptx" "$work/kernels.cu" 2> "$work/nvcc.txt"; then
            export DIFFCASSI_PTX="$work/kernels.ptx"
            echo "gpu_check: $(nvcc --version | tail -1): a fallback PTX for a driver that refuses the embedded one"
        else
            echo "gpu_check: nvcc could not build the fallback PTX: $(head -c 2000 "$work/nvcc.txt")"
        fi
    else
        echo "gpu_check: no nvcc on PATH: no fallback PTX file"
    fi
    echo "gpu_check: NVRTC for the launcher's last fallback: ${nvrtc_dir:-none found beside torch}"
fi
status=0
budget="${CHECK_BUDGET_S:-400}"
# Whole seconds, no leading zero (bash arithmetic would read 0400 as octal 256 and fail on 080).
[[ "$budget" =~ ^(0|[1-9][0-9]{0,5})$ ]] || { echo "gpu_check: CHECK_BUDGET_S=$budget: give whole seconds (no leading zero)" >&2; exit 2; }
# The seconds a step may take: its own cap, at most what is left of the budget (0: too little left to start).
cap() {
    local left=$(( budget - SECONDS ))
    (( left > $1 )) && left=$1
    (( left >= 20 )) && echo "$left" || echo 0
}
# step NAME CAP LOG COMMAND...: run within its cap, its output teed to LOG; a failure or a skip fails the check.
step() {
    local name="$1" t; t="$(cap "$2")"; local log="$3"; shift 3
    if (( t == 0 )); then
        echo "gpu_check: $name not started: under 20 s left of CHECK_BUDGET_S=$budget" | tee "$log"
        status=1
        return
    fi
    timeout "$t" "$@" 2>&1 | tee "$log"
    local rc=${PIPESTATUS[0]}
    (( rc == 124 )) && echo "gpu_check: $name stopped at its cap of $t s" | tee -a "$log"
    (( rc == 0 )) || status=1
}
step "render check" 300 "$out/render_check.txt" "$vpy" "$root/scripts/gpu/render_check.py" --out "$out" "${render_args[@]}" ${RENDER_ARGS:-}
step "systems check" 150 "$out/render_systems_check.txt" "$vpy" "$root/scripts/gpu/render_check.py" --systems --out "$out" "${systems_args[@]}" ${RENDER_ARGS:-}
if [[ -f "$root/scripts/gpu/torch_check.py" ]]; then
    step "torch check" 240 "$out/torch_check.txt" "$vpy" "$root/scripts/gpu/torch_check.py" --out "$out" "${torch_args[@]}"
fi
echo "gpu_check: $([[ $dry == 1 ]] && echo "DRY RUN ")$([[ $status -eq 0 ]] && echo passed || echo FAILED); records in $out"
exit $status
