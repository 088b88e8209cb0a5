#!/usr/bin/env bash
# The real Slurm test (issue 17; docs/slurm.md): a one-node Slurm cluster started here, a 4-task job array
# over 12 small scenes (wavelengths from .npy files) through scripts/slurm/render-array.sbatch, one task killed in the middle of a scene,
# a resubmission, and checks that
#   - every scene was rendered exactly once (from the tasks' JSON Lines; the scene in flight when the task
#     was killed is rendered by the resubmission),
#   - no temporary files or folders are left,
#   - every output is byte-identical to a single-machine `render-dataset` run (render.json: timing fields aside),
#   - `dataset-status` is clean, and a second submission of the whole array renders nothing.
#
# How: munged (own key and socket), slurmctld and slurmd (NodeName=localhost, `slurmd -N localhost`) run as
# root in a private network namespace (`unshare -n`; 127.0.0.2/8 added to lo, without which Debian 12's
# Slurm 22.05 slurmctld loops on getaddrinfo), with every file in a temporary folder and the configuration
# passed by SLURM_CONF / -f (nothing under /etc is read or written). ProctrackType=proctrack/linuxproc:
# without systemd the cgroup tracker marks jobs COMPLETED that never ran. No slurmdbd, so no sacct: jobs
# are followed with squeue/scontrol. Every daemon started here is stopped by PID on exit.
#
# Prints `SKIP: <reason>` and exits 0 when it cannot run here: not root, Slurm/munge not installed
# (scripts/setup.sh installs them), or no network namespace (e.g. an unprivileged container).
# Environment: DIFFCASSI_BIN (default target/release/diffcassi, built if missing); KEEP=1 keeps the
# temporary folder (its path is printed) for inspection.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
SELF="$ROOT/tests/slurm/run.sh"
SBATCH_SCRIPT="$ROOT/scripts/slurm/render-array.sbatch"

skip() {
    echo "SKIP: Slurm test: $*"
    exit 0
}
fail() {
    echo "FAIL: Slurm test: $*" >&2
    exit 1
}

if [[ "${1:-}" != --inside-namespace ]]; then
    [[ "$(id -u)" -eq 0 ]] || skip "needs root (a network namespace and Slurm daemons running as root)"
    for tool in munged mungekey munge slurmctld slurmd sbatch squeue scontrol scancel sinfo ip unshare jq awk; do
        command -v "$tool" >/dev/null 2>&1 || skip "'$tool' not installed (scripts/setup.sh installs munge, slurmctld, slurmd, slurm-client, jq)"
    done
    if ! err=$(unshare -n true 2>&1); then
        skip "cannot create a network namespace (unshare -n: ${err:-failed})"
    fi
    BIN=${DIFFCASSI_BIN:-$ROOT/target/release/diffcassi}
    if [[ -z "${DIFFCASSI_BIN:-}" && ! -x "$BIN" ]]; then
        (cd "$ROOT" && cargo build --release --bin diffcassi)
    fi
    [[ -x "$BIN" ]] || fail "diffcassi binary not found: $BIN"
    export DIFFCASSI_BIN="$BIN"
    exec unshare -n -- bash "$SELF" --inside-namespace
fi

# ------------------------------------------------------------------ inside the private network namespace
START=$(date +%s.%N)
BIN=$DIFFCASSI_BIN
T=$(mktemp -d /tmp/diffcassi-slurm-test.XXXXXX)
chmod 700 "$T"
PIDS=()

stop_daemons() {
    local rc=$?
    set +e
    if [[ -n "${SLURM_CONF:-}" ]] && ((${#PIDS[@]} > 1)); then
        scancel --quiet --full "--user=$(id -un)" >/dev/null 2>&1
    fi
    # Stop in reverse order of start (slurmd, slurmctld, munged), each by its PID.
    local i pid
    for ((i = ${#PIDS[@]} - 1; i >= 0; i--)); do
        pid=${PIDS[i]}
        kill "$pid" 2>/dev/null
        for _ in $(seq 50); do
            kill -0 "$pid" 2>/dev/null || break
            sleep 0.1
        done
        kill -0 "$pid" 2>/dev/null && kill -9 "$pid" 2>/dev/null
        wait "$pid" 2>/dev/null
    done
    if ((rc != 0)); then
        echo "--- slurmctld.log (tail)" >&2
        tail -n 20 "$T/slurmctld.log" >&2 2>/dev/null
        echo "--- slurmd.log (tail)" >&2
        tail -n 20 "$T/slurmd.log" >&2 2>/dev/null
        for f in "$T"/logs/*.err; do
            [[ -s "$f" ]] && { echo "--- $f" >&2; tail -n 5 "$f" >&2; }
        done
    fi
    if [[ "${KEEP:-0}" == 1 || $rc -ne 0 ]]; then
        echo "Slurm test: state kept in $T" >&2
    else
        rm -rf "$T"
    fi
    exit "$rc"
}
trap stop_daemons EXIT
trap 'exit 130' INT TERM

ip link set lo up
# Slurm 22.05's slurmctld loops on a failing getaddrinfo when 127.0.0.1 is the only address.
ip addr add 127.0.0.2/8 dev lo

# --- munge: own key, socket, pid, log and seed files.
mkdir -p "$T/munge" "$T/state" "$T/spool" "$T/logs"
chmod 700 "$T/munge"
mungekey --create --keyfile="$T/munge/munge.key" >/dev/null 2>&1 || head -c 1024 /dev/urandom >"$T/munge/munge.key"
chmod 600 "$T/munge/munge.key"
SOCK="$T/munge/munge.sock"
munged --foreground --force --key-file="$T/munge/munge.key" --socket="$SOCK" --pid-file="$T/munge/munged.pid" \
    --log-file="$T/munge/munged.log" --seed-file="$T/munge/munged.seed" >"$T/munge/stdout.log" 2>&1 &
PIDS+=($!)
for _ in $(seq 50); do
    munge --socket="$SOCK" --no-input >/dev/null 2>&1 && break
    sleep 0.1
done
munge --socket="$SOCK" --no-input >/dev/null 2>&1 || fail "munged did not start ($(tail -n 3 "$T/munge/munged.log" 2>/dev/null))"

# --- Slurm: one node of 4 CPUs (config_overrides: the machine may have fewer), everything under $T.
export SLURM_CONF="$T/slurm.conf"
cat >"$SLURM_CONF" <<EOF
ClusterName=diffcassi-test
SlurmctldHost=localhost
AuthType=auth/munge
AuthInfo=socket=$SOCK
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/slurmctld.pid
SlurmdPidFile=$T/slurmd.pid
SlurmctldLogFile=$T/slurmctld.log
SlurmdLogFile=$T/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SlurmdParameters=config_overrides
ReturnToService=2
KillWait=2
MinJobAge=600
NodeName=localhost NodeAddr=127.0.0.1 CPUs=4 RealMemory=2000 State=UNKNOWN
PartitionName=test Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF
slurmctld -D -c -f "$SLURM_CONF" >"$T/slurmctld.stdout" 2>&1 &
PIDS+=($!)
slurmd -D -N localhost -f "$SLURM_CONF" >"$T/slurmd.stdout" 2>&1 &
PIDS+=($!)
for _ in $(seq 150); do
    [[ "$(sinfo -h -o %T 2>/dev/null)" == idle ]] && break
    sleep 0.2
done
[[ "$(sinfo -h -o %T 2>/dev/null)" == idle ]] || fail "the node did not become idle: $(sinfo 2>&1 | tail -n 2)"
echo "Slurm test: $(sinfo --version), one node up in a private network namespace ($T)"

# --- 12 scenes of 16×16 pixels whose wavelengths come from .npy files (`make-scene` writes sNN.npy, its
# sNN_wavelengths_nm.npy: 28 bands 450–650 nm, whose decimals such as 464.81481481481484 the best-effort
# JSON float parser read back one ulp off, so later tasks refused the first tasks' dataset.json — issue 21),
# rendered at the same 28 bands.
mkdir -p "$T/scenes"
for i in $(seq -w 0 11); do
    "$BIN" make-scene --synthetic "$((10#$i))" --size 16 --bands 450:650:28 --out "$T/scenes/s$i.npy" >/dev/null 2>"$T/make-scene.err" ||
        fail "make-scene failed: $(tail -n 3 "$T/make-scene.err")"
    [[ -f "$T/scenes/s${i}_wavelengths_nm.npy" ]] || fail "make-scene wrote no wavelength file for s$i"
done
SCENES=12
SHARDS=4
RENDER=(--scenes "$T/scenes" --preset sp --scene-size 16 --planes 28 --bands 450:650:28 --rays 2)

# --- The single-machine reference.
"$BIN" render-dataset "${RENDER[@]}" --out "$T/ref" >"$T/ref.jsonl" 2>"$T/ref.err" || fail "reference render-dataset failed: $(tail -n 3 "$T/ref.err")"
[[ $(grep -c '"status":"rendered"' "$T/ref.jsonl") -eq $SCENES ]] || fail "reference: expected $SCENES rendered scenes"

cd "$T"
submit() { # submit NAME [sbatch options...] -- prints the job id
    local name=$1
    shift
    sbatch --parsable --cpus-per-task=1 --mem=100M --output="$T/logs/$name-%a.out" --error="$T/logs/$name-%a.err" "$@" \
        "$SBATCH_SCRIPT" "${RENDER[@]}" --out "$T/out" | cut -d';' -f1
}
wait_job() { # wait_job JOBID TIMEOUT_S (squeue polling: sbatch --wait polls slowly)
    local t0=$SECONDS
    while [[ -n "$(squeue -h -j "$1" -o %i 2>/dev/null)" ]]; do
        ((SECONDS - t0 < $2)) || fail "job $1 still queued/running after $2 s: $(squeue -j "$1" 2>&1 | tail -n 4)"
        sleep 0.2
    done
}
task_state() { # task_state JOBID TASK
    scontrol -o show job "$1" 2>/dev/null | awk -v t="ArrayTaskId=$2" '$0 ~ t" " { for (i = 1; i <= NF; i++) if ($i ~ /^JobState=/) { sub("JobState=", "", $i); print $i } }'
}

# --- 1. The whole array; each scene waits 1.5 s before its folder is moved into place (test hook), so that
# a task can be killed in flight.
JOB1=$(DIFFCASSI_DEBUG_SCENE_DELAY_MS=1500 submit run1 --array=0-$((SHARDS - 1)))
victim=
for _ in $(seq 600); do
    partial=$(find "$T/out" -maxdepth 1 -name '.*.partial-*' -print -quit 2>/dev/null || true)
    if [[ -n "$partial" ]]; then
        scene=$(basename "$partial")
        scene=${scene#.}
        scene=${scene%%.partial-*}
        victim=$((10#${scene#s} % SHARDS))
        break
    fi
    sleep 0.05
done
[[ -n "$victim" ]] || fail "no scene in flight seen within 30 s"
scancel "${JOB1}_${victim}"
echo "Slurm test: job $JOB1 submitted ($SHARDS tasks); killed task $victim while scene $scene was in flight"
wait_job "$JOB1" 60
for k in $(seq 0 $((SHARDS - 1))); do
    st=$(task_state "$JOB1" "$k")
    if ((k == victim)); then
        [[ "$st" == CANCELLED* ]] || fail "task ${JOB1}_$k: state $st, expected CANCELLED"
    else
        [[ "$st" == COMPLETED ]] || fail "task ${JOB1}_$k: state $st, expected COMPLETED ($(tail -n 3 "$T/logs/run1-$k.err"))"
    fi
done
# The killed task left its scene's temporary folder and no folder for the scene; the status says so.
[[ -d "$partial" ]] || fail "the kill did not land mid-scene: $partial is gone"
[[ ! -e "$T/out/$scene" ]] || fail "the killed task's in-flight scene $scene has an output folder"
if "$BIN" dataset-status "$T/out" --json >"$T/status1.json" 2>/dev/null; then
    fail "dataset-status is clean after a killed task"
fi
missing=$(jq '.counts.missing' "$T/status1.json")
[[ "$missing" -ge 1 && $(jq '.counts.corrupt' "$T/status1.json") -eq 0 ]] || fail "after the kill: $(jq -c .counts "$T/status1.json")"

# --- 2. Resubmit the killed index alone (Slurm then reports a count of 1: DIFFCASSI_SHARDS gives N).
JOB2=$(DIFFCASSI_SHARDS=$SHARDS submit resub --array="$victim")
wait_job "$JOB2" 60
[[ "$(task_state "$JOB2" "$victim")" == COMPLETED ]] || fail "resubmitted task: $(task_state "$JOB2" "$victim") ($(tail -n 3 "$T/logs/resub-$victim.err"))"
resub_rendered=$(grep -c '"status":"rendered"' "$T/logs/resub-$victim.out" || true)
[[ "$resub_rendered" -eq "$missing" ]] || fail "the resubmission rendered $resub_rendered scenes, $missing were missing"

# Every scene rendered exactly once over both submissions (the in-flight scene of the killed task was
# never committed, so it has no line from that task).
cat "$T"/logs/run1-*.out "$T"/logs/resub-*.out >"$T/all.jsonl"
for i in $(seq -w 0 11); do
    n=$(jq -r --arg s "s$i" 'select(.scene == $s and .status == "rendered") | .scene' "$T/all.jsonl" | wc -l)
    [[ "$n" -eq 1 ]] || fail "scene s$i rendered $n times"
done
[[ $(jq -r 'select(.status == "failed")' "$T/all.jsonl" | wc -l) -eq 0 ]] || fail "failed scenes: $(grep failed "$T/all.jsonl")"

# No temporary files or folders anywhere (the resubmitted shard removed the killed task's).
left=$(find "$T/out" -name '.*' -o -name '*.tmp' -o -name '*.partial-*')
[[ -z "$left" ]] || fail "temporaries left: $left"

# Byte-identical to the single-machine run (render.json: timing and run-circumstance fields aside).
strip='del(.threads, .seconds_total, .seconds_render, .timings, .rays_per_second, .transport_seconds, .seconds_scene, .transport_cached)'
diff <(cd "$T/ref" && find . -type f | sort) <(cd "$T/out" && find . -type f | sort) >/dev/null || fail "file lists differ: $(diff <(cd "$T/ref" && find . -type f | sort) <(cd "$T/out" && find . -type f | sort) | head)"
files=0
while read -r f; do
    if [[ "$(basename "$f")" == render.json ]]; then
        cmp -s <(jq -S "$strip" "$T/ref/$f") <(jq -S "$strip" "$T/out/$f") || fail "$f differs from the single-machine run"
    else
        cmp -s "$T/ref/$f" "$T/out/$f" || fail "$f differs from the single-machine run"
    fi
    files=$((files + 1))
done < <(cd "$T/ref" && find . -type f | sort)

"$BIN" dataset-status "$T/out" --scenes "$T/scenes" >"$T/status2.txt" 2>&1 || fail "dataset-status not clean: $(tail -n 5 "$T/status2.txt")"

# --- 3. A second submission of the whole array renders nothing.
JOB3=$(submit again --array=0-$((SHARDS - 1)))
wait_job "$JOB3" 60
cat "$T"/logs/again-*.out >"$T/again.jsonl"
[[ $(jq -r 'select(.status == "skipped") | .scene' "$T/again.jsonl" | sort -u | wc -l) -eq $SCENES ]] || fail "second submission: $(cat "$T/again.jsonl")"
[[ $(jq -r 'select(.status != "skipped")' "$T/again.jsonl" | wc -l) -eq 0 ]] || fail "second submission rendered something"
for k in $(seq 0 $((SHARDS - 1))); do
    [[ "$(task_state "$JOB3" "$k")" == COMPLETED ]] || fail "second submission task $k: $(task_state "$JOB3" "$k")"
done

elapsed=$(awk -v a="$START" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
echo "Slurm test: ok in ${elapsed} s: $SCENES scenes over $SHARDS array tasks, task $victim killed mid-scene ($scene) and resubmitted ($missing scenes finished), each scene rendered once, $files files identical to the single-machine run, dataset-status clean, a second submission skipped all"
