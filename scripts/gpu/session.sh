#!/usr/bin/env bash
# The one call of a GPU session (docs/gpu.md, "A GPU session, step by step"): the GPU check of issue 41, then a
# short training run of issue 43, inside one device call, and what they wrote packed into what the device tool
# brings back. On the GPU machine, from the carried wheel (carry ["dist", ".whl"]):
#
#     bash scripts/gpu/session.sh                  # OUT: the device tool's $OUT (default gpu_out/session)
#
# Time: SESSION_BUDGET_S seconds in all (default 540, under the tool's 600 s a call): the check gets at most
# min(400, budget − 140) s (scripts/gpu_check.sh, CHECK_BUDGET_S 20 s below its cap); the training gets what is
# left once the check is done, less 20 s for the packing: `train_run.sh` stops the training at its BUDGET_S and
# kills it at BUDGET_S + 90 s, and spends ~30 s installing and importing, so BUDGET_S = left − 120 (under 30 s:
# no training, said). TRAIN_BUDGET_S fixes the training's budget instead (the dry run).
#
# Output: the device tool brings back at most 8 files, each ≤ 16 MiB and 64 MiB in all, no more than two folders
# down. The check's ~8 files and the training's 6 would not all come back (a held-out battery, round 15), so they
# are packed into $OUT: session.txt (what ran, the exit statuses, seconds), check.tar.gz (the check's tables and
# JSON records), train.tar.gz (the training's log, manifest and tables), and the training's weights and
# checkpoint as they are (the next RESUME; each checked ≤ 16 MiB, else split into 15 MiB parts). The script
# checks those limits itself and says so. At the end it prints the check's tables again: the tool's output tail
# keeps the last 12 000 characters, which the training's log would otherwise fill.
#
# The training runs after a failed check too (a check can fail on one row; the training's figures are still the
# GPU's), and session.txt says each step's status. Each `timeout` sends SIGKILL 15 s after SIGTERM (a hung CUDA
# call may ignore SIGTERM). An earlier session's outputs in $OUT are replaced; another non-empty $OUT is refused.
#
# Environment passed on: DRY_RUN (gpu_check.sh), DEVICE, RESUME, WORKERS (train_run.sh), PYTHON (both).
# Exit: the check's status; else the training's; else 3 when the training was not started (no time left).
set -uo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
out="${OUT:-$root/gpu_out/session}"
budget="${SESSION_BUDGET_S:-540}"
[[ "$budget" =~ ^[1-9][0-9]{0,5}$ ]] && (( budget >= 200 )) || { echo "session: SESSION_BUDGET_S=$budget: give whole seconds, at least 200" >&2; exit 2; }
mkdir -p "$out"
out="$(cd "$out" && pwd)"
# An earlier session's outputs (its session.txt marks them) are replaced; a folder holding anything else is not
# this script's to clear: refused.
if [[ -n "$(ls -A "$out")" && ! -f "$out/session.txt" ]]; then
    echo "session: $out is not empty and holds no earlier session's output (session.txt): give an empty OUT" >&2
    exit 2
fi
rm -f "$out"/session.txt "$out"/check.tar.gz "$out"/train.tar.gz "$out"/unrolled-*.safetensors* "$out"/unrolled-*-checkpoint.pt*
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
log="$out/session.txt"
say() { echo "session: $*" | tee -a "$log"; }
: > "$log"
say "start $(date -u +%FT%TZ); budget ${budget} s; out $out"

# 1. The check.
check_cap=$(( budget - 140 < 400 ? budget - 140 : 400 ))
(( check_cap < 60 )) && check_cap=60
t0=$SECONDS
CHECK_BUDGET_S=$(( check_cap - 20 )) OUT="$work/check" timeout -k 15 "$check_cap" bash "$root/scripts/gpu_check.sh"
check_rc=$?
say "check: exit $check_rc$( (( check_rc == 124 || check_rc == 137 )) && echo " (stopped at its cap)") in $(( SECONDS - t0 )) s (cap ${check_cap} s)"

# 2. The training, in what is left.
left=$(( budget - SECONDS - 20 ))
train_budget="${TRAIN_BUDGET_S:-$(( left - 120 ))}"
train_rc=3
if [[ -n "${TRAIN_BUDGET_S:-}" ]] || (( train_budget >= 30 )); then
    t0=$SECONDS
    BUDGET_S="$train_budget" OUT="$work/train" timeout -k 15 $(( left > 60 ? left : 60 )) bash "$root/scripts/gpu/train_run.sh"
    train_rc=$?
    say "training: exit $train_rc$( (( train_rc == 124 || train_rc == 137 )) && echo " (stopped at its cap)") in $(( SECONDS - t0 )) s (BUDGET_S ${train_budget})"
else
    say "training: NOT STARTED: ${left} s left of the session's budget, under 150 s (exit 3)"
fi

# 3. Packed into at most 8 files.
if [[ -d "$work/check" ]]; then
    tar -C "$work" -czf "$out/check.tar.gz" check
fi
if [[ -d "$work/train" ]]; then
    # The weights and the checkpoint as they are; the rest (log, manifest, tables) in one archive.
    big=()
    for f in "$work"/train/*.safetensors "$work"/train/*-checkpoint.pt; do
        [[ -f "$f" ]] && big+=("$f")
    done
    for f in "${big[@]}"; do
        if (( $(stat -c %s "$f") > 16 * 1024 * 1024 )); then
            split -b 15M -d "$f" "$out/$(basename "$f").part-"
            say "$(basename "$f") is over 16 MiB: split into $(basename "$f").part-NN (cat them back together)"
        else
            cp "$f" "$out/"
        fi
        rm -f "$f"
    done
    tar -C "$work" -czf "$out/train.tar.gz" train
fi
files=$(find "$out" -type f | wc -l)
bytes=$(du -sb "$out" | cut -f1)
over=$(find "$out" -type f -size +16M | wc -l)
deep=$(find "$out" -mindepth 4 -type f | wc -l)  # $OUT/a/b/file comes back, $OUT/a/b/c/file does not
say "out: $files files, $(( bytes / 1024 / 1024 )) MiB: $(cd "$out" && ls | tr '\n' ' ')"
if (( files > 8 || over > 0 || bytes > 64 * 1024 * 1024 || deep > 0 )); then
    say "WARNING: beyond what the device tool brings back (8 files, 16 MiB each, 64 MiB in all, two folders down)"
fi

# 4. The check's tables again, last, for the output tail.
for t in render_check render_systems_check torch_check; do
    [[ -f "$work/check/$t.txt" ]] && { echo "---- $t"; tail -25 "$work/check/$t.txt"; }
done
say "done $(date -u +%FT%TZ): check exit $check_rc, training exit $train_rc, ${SECONDS} s"
(( check_rc != 0 )) && exit "$check_rc"
exit "$train_rc"
