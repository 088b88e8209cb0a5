#!/usr/bin/env bash
# The GPU check of issue 41 (docs/gpu.md), run on a GPU machine from the wheel and nothing else (no Rust, no
# network; the machine's Python with numpy and torch):
#
#     bash scripts/gpu_check.sh [WHEEL]        # default: the newest dist/diffcassi-*.whl
#
# Installs the wheel with `pip install --no-deps --no-index` into a throwaway venv that sees the machine's
# site packages, prints the GPU, then runs
#   scripts/gpu/render_check.py  — the paper-scale acquisition on the GPU (twice), the CPU and the host twin,
#                                  the middle plane's landings on both;
#   scripts/gpu/render_check.py --systems — the same checks on small renders of a grating (gsp), a toroid lens,
#                                  an object at infinity and SP with real ray aiming (≈ 1 minute);
#   scripts/gpu/torch_check.py   — the exact operator and the torch modules on CUDA tensors (if present);
# prints their tables and writes their JSON records to $OUT (or gpu_out/). Exits non-zero if any check fails.
# Budget: ≤ 8 minutes on an H200 (the host twin dominates on few cores; RENDER_ARGS=--no-twin skips it; the
# --systems step is four 128² renders and their twins, ≈ 1 minute, capped at 150 s).
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
wheel="${1:-$(ls -t "$root"/dist/diffcassi-*.whl 2>/dev/null | head -1)}"
if [[ -z "$wheel" || ! -f "$wheel" ]]; then
    echo "gpu_check: no wheel given and none in dist/ (build one with scripts/build_wheel.sh)" >&2
    exit 2
fi
out="${OUT:-$root/gpu_out}"
mkdir -p "$out"
py="${PYTHON:-python3}"
work="$(mktemp -d)"
"$py" -m venv --system-site-packages "$work/venv" || { echo "gpu_check: cannot make a venv with $py" >&2; exit 2; }
"$work/venv/bin/pip" install -q --no-deps --no-index "$wheel" || { echo "gpu_check: pip could not install $wheel" >&2; exit 2; }
vpy="$work/venv/bin/python"
echo "gpu_check: $(basename "$wheel") into $("$vpy" -c 'import sys; print(sys.version.split()[0])'); $(date -u +%FT%TZ)"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | tee "$out/gpu.txt"
# Run from an empty folder, so that `import diffcassi` is the wheel's and not a source tree's.
cd "$work"
# A driver older than the NVRTC that wrote the embedded PTX refuses it: the launcher then reads DIFFCASSI_PTX,
# built here with the machine's own nvcc from the kernel source the wheel carries.
if command -v nvcc >/dev/null 2>&1 && [[ -z "${DIFFCASSI_PTX:-}" ]]; then
    if "$vpy" -c 'import diffcassi._native as n; print(n._gpu_kernel_source())' > "$work/kernels.cu" \
        && nvcc -ptx -arch=compute_90 --fmad=false -o "$work/kernels.ptx" "$work/kernels.cu" 2> "$out/nvcc.txt"; then
        export DIFFCASSI_PTX="$work/kernels.ptx"
    else
        echo "gpu_check: nvcc could not build the fallback PTX ($out/nvcc.txt); the embedded PTX only"
    fi
fi
status=0
timeout 420 "$vpy" "$root/scripts/gpu/render_check.py" --out "$out" ${RENDER_ARGS:-} 2>&1 | tee "$out/render_check.txt"
[[ ${PIPESTATUS[0]} -eq 0 ]] || status=1
timeout 150 "$vpy" "$root/scripts/gpu/render_check.py" --systems --out "$out" ${RENDER_ARGS:-} 2>&1 | tee "$out/render_systems_check.txt"
[[ ${PIPESTATUS[0]} -eq 0 ]] || status=1
if [[ -f "$root/scripts/gpu/torch_check.py" ]]; then
    timeout 240 "$vpy" "$root/scripts/gpu/torch_check.py" --out "$out" 2>&1 | tee "$out/torch_check.txt"
    [[ ${PIPESTATUS[0]} -eq 0 ]] || status=1
fi
echo "gpu_check: $([[ $status -eq 0 ]] && echo passed || echo FAILED); records in $out"
exit $status
