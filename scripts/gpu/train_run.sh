#!/usr/bin/env bash
# One short training run of the unrolled network unrolled-dauhst-v2 on a GPU machine (issue 43 item 3): resumes
# from a checkpoint (default the committed initial one, diffcassi/weights/unrolled-dauhst-v2-sp-init.pt) on CUDA,
# stops cleanly inside its time budget and writes the checkpoint, the weights, the JSONL log and the manifest (every
# run so far, with its steps and data seeds) to $OUT. Run on a machine without Rust, from the wheel:
#
#     bash scripts/gpu/train_run.sh [WHEEL]       # default: the newest dist/diffcassi-*.whl
#
# Environment: OUT (default gpu_out/train), RESUME (a checkpoint; the next run resumes from the previous run's
# $OUT/unrolled-dauhst-v2-sp-checkpoint.pt, carried back), BUDGET_S (the training's wall-time budget, default 450:
# with the install the call stays under 9 minutes), WORKERS (processes making the cubes, default nproc − 2),
# PYTHON (default python3; a venv is fine, as on the GPU machine), DEVICE (default cuda; DEVICE=cpu with a tiny
# RESUME is the dry run on a development machine: scripts/gpu/prepare.sh runs it on a copy of the tree, since
# this script puts the wheel's compiled module into the tree's diffcassi/). The settings (system, size, schedule, mask, seeds) are the checkpoint's.
#
# Needs: the diffcassi wheel (its compiled module is used with this tree's Python files, so the tree's
# diffcassi/unrolled.py and training_data.py are the ones that run), torch with CUDA, safetensors, scikit-image
# (its shipped sample images) and colour-science — absent from the GPU image: scripts/setup.sh puts its wheel
# (pure Python) in .whl/; carry `.whl` and `dist`. Exits 0 when the run saved its outputs, 2 when something it needs is missing (nothing run),
# else the training's exit status.
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
wheel="${1:-$(ls -t "$root"/dist/diffcassi-*.whl 2>/dev/null | head -1)}"
if [[ -z "$wheel" || ! -f "$wheel" ]]; then
    echo "train_run: no wheel given and none in dist/ (build one with scripts/build_wheel.sh)" >&2
    exit 2
fi
out="${OUT:-$root/gpu_out/train}"
resume="${RESUME:-$root/diffcassi/weights/unrolled-dauhst-v2-sp-init.pt}"
budget="${BUDGET_S:-450}"
workers="${WORKERS:-$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))}"
py="${PYTHON:-python3}"
mkdir -p "$out"
if [[ ! -f "$resume" ]]; then
    echo "train_run: RESUME $resume: no such checkpoint" >&2
    exit 2
fi
device="${DEVICE:-cuda}"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
# A package the machine lacks (colour-science) goes into a folder on PYTHONPATH, not into a venv: the GPU
# machine's python3 is itself a venv (/opt/torch/.venv), and a venv made from a venv sees the base interpreter's
# packages, not the torch and numpy of the one it was made from.
vpy="$py"
export PYTHONPATH="$work/site${PYTHONPATH:+:$PYTHONPATH}"
# The wheel's compiled module beside this tree's Python files (train_unrolled.py imports the tree's diffcassi).
"$vpy" - "$wheel" "$root/diffcassi" <<'EOF' || { echo "train_run: no compiled module in $wheel" >&2; exit 2; }
import sys, zipfile, pathlib
z = zipfile.ZipFile(sys.argv[1])
so = [n for n in z.namelist() if n.startswith("diffcassi/_native") and n.endswith(".so")]
if not so:
    sys.exit(1)
pathlib.Path(sys.argv[2], pathlib.Path(so[0]).name).write_bytes(z.read(so[0]))
print("train_run: compiled module", so[0], "from", sys.argv[1])
EOF
if ! "$vpy" -c 'import colour' 2>/dev/null; then
    cs="$(ls "$root"/.whl/colour_science-*.whl 2>/dev/null | head -1)"
    if [[ -z "$cs" ]]; then
        echo "train_run: colour-science is not installed and no .whl/colour_science-*.whl was carried" >&2
        exit 2
    fi
    "$vpy" -m pip install -q --disable-pip-version-check --no-deps --no-index --target "$work/site" "$cs" \
        || { echo "train_run: pip could not install $cs into $work/site" >&2; exit 2; }
fi
"$vpy" - "$device" <<'EOF' || exit 2
import sys
missing = []
for m in ("torch", "safetensors", "skimage", "colour", "PIL", "scipy"):
    try:
        __import__(m)
    except Exception as e:
        missing.append(f"{m} ({e})")
if missing:
    sys.exit("train_run: missing Python packages: " + ", ".join(missing))
import torch
if sys.argv[1].startswith("cuda") and not torch.cuda.is_available():
    sys.exit("train_run: torch sees no CUDA device")
EOF
cd "$root"
"$vpy" -c 'import diffcassi.training_data as t; print("train_run: textures", t.check_textures())' || exit 2
echo "train_run: $(basename "$wheel"); device $device; resume $(basename "$resume"); budget ${budget} s; ${workers} workers; $(date -u +%FT%TZ)"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>&1 | tee "$out/gpu.txt"
PYTHONUNBUFFERED=1 timeout $(( ${budget%.*} + 90 )) "$vpy" scripts/train_unrolled.py --resume "$resume" --out "$out" \
    --device "$device" --workers "$workers" --threads 4 --time-budget-s "$budget" --val-every 500 2>&1 | tee "$out/train.txt"
status=${PIPESTATUS[0]}
echo "train_run: exit $status; $(date -u +%FT%TZ); outputs in $out"
exit $status
