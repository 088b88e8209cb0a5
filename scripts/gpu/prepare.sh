#!/usr/bin/env bash
# Make ready what a lent GPU machine runs (issues 41 and 43), and run it here first without a GPU, so that the
# machine's few minutes go to GPU work and not to a script's mistake (docs/gpu.md, "A GPU session"):
#
#   1. the release wheel: scripts/build_wheel.sh → dist/ (incremental after the first build; --no-build keeps
#      the wheel that is there);
#   2. colour-science's wheel in .whl/ (scripts/setup.sh downloads it; the GPU image lacks the package);
#   3. the carry — the tree as the device tool copies it (tracked files and untracked ones git does not ignore)
#      plus dist/ and .whl/ — against the tool's 64 MiB;
#   4. a copy of that carry in a temporary folder (what the GPU machine gets), and in it, with .venv's Python
#      standing in for the GPU machine's python3 (both are venvs, which is what broke the scripts' first form):
#      - DRY_RUN=1 DEVICE=cpu bash scripts/gpu/session.sh, the session's one call: scripts/gpu_check.sh with
#        the wheel installed as there and the host twin standing in for the device, then scripts/gpu/train_run.sh
#        from a tiny checkpoint (made in the copy with the wheel's module): the module taken from the wheel, the
#        package checks, the resume, the budget stop; then the outputs packed as the device tool brings them
#        back (≤ 8 files, 16 MiB each), unpacked here and checked;
#      - colour-science's carried wheel installed as train_run.sh installs it, and imported;
#   5. prints the device tool's call for the GPU session.
#
# Usage: bash scripts/gpu/prepare.sh [--no-build] [--keep] [--python PY]
#   --keep: leave the copy and its outputs; --python PY: the interpreter that stands in for the GPU machine's
#   python3 in step 4 (default .venv's) — e.g. a venv with the GPU machine's torch (2.11), so that its torch reads
#   the checkpoints this machine's torch wrote (docs/gpu.md, "Another torch in the dry run").
# Exit 0 when everything is ready; the dry runs' outputs are under the copy's gpu_out/ (printed).
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
cd "$root"
build=1
keep=0
gpu_py=""
while (($#)); do
    a="$1"
    shift
    case "$a" in
        --no-build) build=0 ;;
        --keep) keep=1 ;;
        --python)
            (($#)) || { echo "prepare.sh: --python needs an interpreter" >&2; exit 2; }
            gpu_py="$1"
            shift
            ;;
        -h | --help) sed -n '2,/^set -uo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "prepare.sh: unknown argument '$a' (usage: bash scripts/gpu/prepare.sh [--no-build] [--keep] [--python PY])" >&2; exit 2 ;;
    esac
done
die() { echo "prepare.sh: error: $*" >&2; exit 1; }
py="$root/.venv/bin/python"
[[ -x "$py" ]] || die "no .venv: run bash scripts/setup.sh"
# The GPU machine's stand-in (step 4); .venv's Python makes the tiny checkpoint either way.
gpu_py="${gpu_py:-$py}"
command -v "$gpu_py" > /dev/null || die "--python $gpu_py: no such interpreter"
echo "prepare.sh: the GPU machine's python3 stands as $gpu_py ($("$gpu_py" -c 'import sys, torch, numpy; print("Python", sys.version.split()[0], "torch", torch.__version__, "numpy", numpy.__version__)' 2>&1 | tail -1))"
start=$SECONDS

# 1. The wheel.
if ((build)); then
    bash scripts/build_wheel.sh || die "scripts/build_wheel.sh failed (above)"
fi
shopt -s nullglob
wheels=(dist/diffcassi-*.whl)
((${#wheels[@]} == 1)) || die "expected one wheel in dist/, found ${#wheels[@]} (run without --no-build)"
wheel="${wheels[0]}"

# 2. colour-science.
cs=(.whl/colour_science-*.whl)
((${#cs[@]} >= 1)) || die "no .whl/colour_science-*.whl: run bash scripts/setup.sh (it downloads it)"

# 3. The carry, as the device tool copies it.
copy="$(mktemp -d /tmp/diffcassi-carry.XXXXXX)"
((keep)) || trap 'rm -rf "$copy"' EXIT
git ls-files -z --cached --others --exclude-standard | while IFS= read -r -d '' f; do [[ -e "$f" ]] && printf '%s\0' "$f"; done \
    | tar --null -T - -cf - | tar -xf - -C "$copy" || die "could not copy the tree to $copy"
mkdir -p "$copy/dist" "$copy/.whl"
cp "$wheel" "$copy/dist/" && cp "${cs[@]}" "$copy/.whl/" || die "could not copy dist/ and .whl/"
bytes=$(du -sb --exclude=.git "$copy" | cut -f1)
limit=$((64 * 1024 * 1024))
echo "prepare.sh: carry $((bytes / 1024 / 1024)) MiB of 64 MiB (tree + $(basename "$wheel") + ${cs[*]##*/})"
((bytes <= limit)) || die "the carry is $bytes bytes, over the device tool's 64 MiB"

status=0
# 4a. A tiny checkpoint for the training's dry run, made in the copy with the wheel's compiled module (the tree's
# in-place module exists only after `maturin develop`, which setup.sh does not run; round 15).
tiny="$copy/gpu_out/tiny"
if ! "$py" - "$copy/dist/$(basename "$wheel")" "$copy/diffcassi" <<'PY' > "$copy/tiny.log" 2>&1; then
import sys, zipfile, pathlib
z = zipfile.ZipFile(sys.argv[1])
so = [n for n in z.namelist() if n.startswith("diffcassi/_native") and n.endswith(".so")]
pathlib.Path(sys.argv[2], pathlib.Path(so[0]).name).write_bytes(z.read(so[0]))
PY
    cat "$copy/tiny.log"
    echo "prepare.sh: FAILED: the wheel's compiled module could not be put into the copy" >&2
    status=1
elif ! (cd "$copy" && "$py" scripts/train_unrolled.py --arch unrolled-dauhst-v2 --system sp --size 8 --bands 3 --stages 1 --width 2 \
        --planes 4 --rays 1 --steps 100000 --batch 2 --warmup 1 --stop-at 0 --threads 1 --workers 0 --out "$tiny") >> "$copy/tiny.log" 2>&1; then
    tail -20 "$copy/tiny.log"
    echo "prepare.sh: FAILED: the tiny checkpoint (log $copy/tiny.log)" >&2
    status=1
fi

# 4b. The session's one call, dry: the GPU check with the host twin standing in for the device, the training on
# the CPU from the tiny checkpoint, the outputs packed as the device tool brings them back (≤ 8 files).
session="$copy/gpu_out/session"
if ((status == 0)); then
    echo "prepare.sh: DRY_RUN=1 DEVICE=cpu scripts/gpu/session.sh in $copy"
    if ! (cd "$copy" && DRY_RUN=1 DEVICE=cpu PYTHON="$gpu_py" RESUME="$tiny/unrolled-dauhst-v2-sp-checkpoint.pt" TRAIN_BUDGET_S=8 WORKERS=1 \
            OUT="$session" bash scripts/gpu/session.sh) > "$copy/session.log" 2>&1; then
        tail -40 "$copy/session.log"
        echo "prepare.sh: FAILED: the session's dry run (log $copy/session.log)" >&2
        status=1
    else
        grep -E "^gpu_check:|^train_run:|^session:|^\| (render check|systems check|check) " "$copy/session.log"
        grep -q "WARNING: beyond what the device tool brings back" "$copy/session.log" && { echo "prepare.sh: FAILED: the session's outputs exceed the device tool's limits" >&2; status=1; }
        mkdir -p "$copy/gpu_out/unpacked"
        for a in check train; do
            tar -C "$copy/gpu_out/unpacked" -xzf "$session/$a.tar.gz" || { echo "prepare.sh: FAILED: no $a.tar.gz in the session's outputs" >&2; status=1; }
        done
        for f in "$session/unrolled-dauhst-v2-sp.safetensors" "$session/unrolled-dauhst-v2-sp-checkpoint.pt" \
                "$copy/gpu_out/unpacked/train/unrolled-dauhst-v2-sp-log.jsonl" "$copy/gpu_out/unpacked/train/unrolled-dauhst-v2-sp-manifest.json" \
                "$copy/gpu_out/unpacked/check/render_check.json" "$copy/gpu_out/unpacked/check/torch_check.json"; do
            [[ -s "$f" ]] || { echo "prepare.sh: FAILED: the session brought back no ${f#$copy/gpu_out/}" >&2; status=1; }
        done
    fi
fi

# 4c. colour-science from the carried wheel, as train_run.sh installs it where the package is missing.
site="$copy/gpu_out/colour-site"
if "$gpu_py" -m pip install -q --disable-pip-version-check --no-deps --no-index --target "$site" "$copy/.whl/$(basename "${cs[0]}")" \
    && PYTHONPATH="$site" "$gpu_py" -c "import colour, os, sys; assert os.path.realpath(colour.__file__).startswith(os.path.realpath(sys.argv[1])), colour.__file__; print('prepare.sh: colour-science', colour.__version__, 'from the carried wheel')" "$site"; then
    :
else
    echo "prepare.sh: FAILED: colour-science's carried wheel does not install or import" >&2
    status=1
fi

if ((status)); then
    echo "prepare.sh: NOT READY ($((SECONDS - start)) s); the copy is kept: $copy" >&2
    trap - EXIT
    exit 1
fi
cat <<EOF
prepare.sh: ready ($((SECONDS - start)) s). For the GPU session (device tool \`run\`, carry ["dist", ".whl"], timeout_s 600):
  bash scripts/gpu/session.sh
(one call: the check, then the training in what is left of 540 s, packed into ≤ 8 files in \$OUT; docs/gpu.md
"A GPU session" says what to commit of them)
EOF
((keep)) && echo "prepare.sh: the copy and its dry-run outputs: $copy"
exit 0
