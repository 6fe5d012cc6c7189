#!/usr/bin/env bash
# A real one-node Slurm cluster on this machine (munged, slurmctld, slurmd from Debian, started
# here with a generated slurm.conf on localhost, in a temporary folder) runs `slscan batch`
# (docs/scale.md): the array over small-rig captures (one zstd-compressed, one corrupt) must
# give outputs byte-identical to a local `slscan reprocess`, the corrupt capture must fail only
# its own task with its message in `batch status`, a finished batch resubmitted must do no work,
# and a task killed half-way must leave nothing that looks done and be redone on resubmission.
# Exit 77 (skipped) with the reason where the cluster cannot start.
#   test_slurm_batch.sh SLSCAN MAKE_BATCH_CAPTURES
set -uo pipefail
SLSCAN=$1
MAKE_CAPTURES=$2

skip() { echo "SKIP: $*"; exit 77; }
fail() { echo "FAIL: $*"; exit 1; }
start=$SECONDS
phase() { echo "[$((SECONDS - start)) s] $*"; }

for tool in munged munge slurmctld slurmd sbatch squeue sinfo scancel; do
  command -v "$tool" >/dev/null 2>&1 || skip "$tool is not installed (scripts/bootstrap.sh installs slurm-wlm, slurmctld, slurmd, munge)"
done
[ "$(id -u)" -eq 0 ] || skip "needs root: slurmd starts each job as its user"

W=$(mktemp -d /tmp/slscan-slurm.XXXXXX)
chmod 755 "$W"
daemons=()
cleanup() {
  if [ -n "${SLURM_CONF:-}" ] && [ ${#daemons[@]} -gt 0 ]; then
    scancel --quiet --full --signal=KILL --user=root 2>/dev/null
    scancel --quiet --user=root 2>/dev/null
    for _ in $(seq 1 20); do [ -z "$(squeue -h 2>/dev/null)" ] && break; sleep 0.5; done
  fi
  for ((i = ${#daemons[@]} - 1; i >= 0; i--)); do kill "${daemons[$i]}" 2>/dev/null; done
  for pid in "${daemons[@]}"; do
    for _ in $(seq 1 20); do kill -0 "$pid" 2>/dev/null || break; sleep 0.25; done
    kill -9 "$pid" 2>/dev/null
  done
  if [ -n "${KEEP:-}" ]; then echo "kept $W"; else rm -rf "$W"; fi
}
trap cleanup EXIT
trap 'exit 130' INT TERM

free_port() {  # a TCP port nobody listens on
  local port hex
  for _ in $(seq 1 50); do
    port=$((20000 + RANDOM % 30000))
    hex=$(printf ':%04X ' "$port")
    grep -q "$hex" /proc/net/tcp /proc/net/tcp6 2>/dev/null || { echo "$port"; return; }
  done
  echo 26817
}

# --- the cluster: munged with its own key and socket, then slurmctld and slurmd
mkdir -p "$W/munge" "$W/state" "$W/spool" "$W/log"
chmod 700 "$W/munge"
head -c 128 /dev/urandom >"$W/munge/munge.key"
chmod 400 "$W/munge/munge.key"
munged -F -f --key-file="$W/munge/munge.key" --socket="$W/munge/munge.socket" --pid-file="$W/munge/munged.pid" \
  --log-file="$W/log/munged.log" --seed-file="$W/munge/munged.seed" >"$W/log/munged.out" 2>&1 &
daemons+=($!)
for _ in $(seq 1 40); do [ -S "$W/munge/munge.socket" ] && break; sleep 0.25; done
munge -S "$W/munge/munge.socket" -n 2>/dev/null | unmunge -S "$W/munge/munge.socket" >/dev/null 2>&1 ||
  skip "munged did not start: $(tail -n 3 "$W/log/munged.out" | tr '\n' ' ')"

node=$(hostname -s)
cpus=$(nproc)
memory_mb=$(($(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 512))
: >"$W/plugstack.conf"
cat >"$W/slurm.conf" <<CONF
ClusterName=slscantest
SlurmctldHost=${node}(127.0.0.1)
SlurmctldPort=$(free_port)
SlurmdPort=$(free_port)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$W/munge/munge.socket
CredType=cred/munge
StateSaveLocation=$W/state
SlurmdSpoolDir=$W/spool
SlurmctldPidFile=$W/slurmctld.pid
SlurmdPidFile=$W/slurmd.pid
SlurmctldLogFile=$W/log/slurmctld.log
SlurmdLogFile=$W/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/builtin
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
SwitchType=switch/none
ReturnToService=2
PlugStackConfig=$W/plugstack.conf
NodeName=${node} NodeAddr=127.0.0.1 CPUs=${cpus} RealMemory=${memory_mb} State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$W/slurm.conf
slurmctld -D -f "$SLURM_CONF" >"$W/log/slurmctld.out" 2>&1 &
daemons+=($!)
slurmd -D -f "$SLURM_CONF" -N "$node" >"$W/log/slurmd.out" 2>&1 &
daemons+=($!)
up=
for _ in $(seq 1 60); do
  state=$(sinfo -h -o %T 2>/dev/null | head -n1)
  case "$state" in idle* | mixed* | allocated*) up=1; break ;; esac
  sleep 0.5
done
[ -n "$up" ] || skip "the one-node Slurm cluster did not come up (node state '${state:-none}'): $(tail -n 2 "$W/log/slurmctld.out" "$W/log/slurmd.out" 2>/dev/null | tr '\n' ' ')"
phase "cluster up: node $node, $cpus CPUs, ${memory_mb} MB"

# --- inputs: three small-rig captures (c compressed) and a corrupt copy of a
"$MAKE_CAPTURES" "$W/in" || fail "make_batch_captures"
cp "$W/in/a.slcap" "$W/in/d.slcap"
size=$(stat -c %s "$W/in/d.slcap")
printf '\x5a\xa5\x5a\xa5' | dd of="$W/in/d.slcap" bs=1 seek=$((size / 2)) conv=notrunc status=none
CAL=$W/in/calib.json
CFG=$W/in/config.json

phase "inputs written"
# --- the reference: local reprocess of each capture
for c in a b c; do
  "$SLSCAN" -q reprocess "$W/in/$c.slcap" --calib "$CAL" --config "$CFG" --out "$W/local/$c" ||
    fail "local reprocess of $c.slcap"
done

# Every output byte-identical, except the wall-clock timings of the stages and the run's start
# (with the calibration's age at it) in report.json and report.html (they differ between any two
# runs, local ones too): those are compared without their figures.
untimed() {
  case "$1" in
    *.json) sed -E '/"(stage|fuse_step)_ms": \{/,/\}/d; /"[a-z_]+_ms": /d; /"started_utc": /d; /"age_days": /d' "$1" ;;
    *) sed -E '/ ms<\/td>|\(ms\)/d; s/started [0-9T:Z-]+//; s/[0-9.]+ days before the run//' "$1" ;;
  esac
}
same_outputs() {  # same_outputs LOCAL BATCH
  diff -r -x report.json -x report.html "$1" "$2" >"$W/diff.txt" 2>&1 ||
    fail "$2 differs from the local reprocess $1: $(head -n 5 "$W/diff.txt")"
  for f in report.json report.html; do
    cmp -s <(untimed "$1/$f") <(untimed "$2/$f") || fail "$2/$f differs from $1/$f beyond the timings"
  done
  [ -s "$2/model.ply" ] || fail "$2 has no model.ply"
}

submit() {  # submit [sbatch options]: submits ROOT/batch.sbatch and waits for it (polling
  # squeue every 0.2 s: sbatch --wait polls far more slowly)
  local id
  id=$(sbatch --parsable "$@" "$ROOT/batch.sbatch") || fail "sbatch $*"
  for _ in $(seq 1 1500); do [ -z "$(squeue -h -j "${id%%;*}" 2>/dev/null)" ] && return 0; sleep 0.2; done
  fail "job $id did not finish in 5 minutes"
}
ROOT=$W/batch
"$SLSCAN" batch plan "$W/in/a.slcap" "$W/in/b.slcap" "$W/in/c.slcap" "$W/in/d.slcap" --calib "$CAL" \
  --config "$CFG" --out "$ROOT" || fail "batch plan"
grep -q -- '--array=0-3' "$ROOT/batch.sbatch" || fail "the array is not over the 4 jobs: $(grep array "$ROOT/batch.sbatch")"
submit
phase "first run finished"
"$SLSCAN" batch status "$ROOT" | tee "$W/status1.txt"
grep -q "4 jobs: 3 done, 1 failed, 0 running, 0 pending" "$W/status1.txt" || fail "status after the first run"
grep -q "3 failed .*d.slcap.*offset" "$W/status1.txt" || fail "the corrupt capture's failure does not say where"
[ ! -e "$ROOT/jobs/3/out" ] && [ ! -e "$ROOT/jobs/3/done.json" ] || fail "the failed job left outputs"
same_outputs "$W/local/a" "$ROOT/jobs/0/out"
same_outputs "$W/local/b" "$ROOT/jobs/1/out"
same_outputs "$W/local/c" "$ROOT/jobs/2/out"
echo "outputs byte-identical to local reprocess but for the stage timings (a, b raw; c zstd)"

# --- resubmitting a finished batch does no work: the plan's array is the failed job only,
# and even the full array skips every done job
stamp() { stat -c '%.9Y' "$ROOT"/jobs/{0,1,2}/done.json | md5sum; }
before=$(stamp)
"$SLSCAN" -q batch plan "$W/in/a.slcap" "$W/in/b.slcap" "$W/in/c.slcap" "$W/in/d.slcap" --calib "$CAL" \
  --config "$CFG" --out "$ROOT" || fail "second plan"
grep -q -- '--array=3$' "$ROOT/batch.sbatch" || fail "second plan: $(grep array "$ROOT/batch.sbatch")"
submit --array=0-2
grep -q "is done already" "$ROOT/logs/task-1.log" || fail "a done task did not skip: $(cat "$ROOT/logs/task-1.log")"
[ "$before" = "$(stamp)" ] || fail "resubmission redid done jobs"
phase "resubmission skipped the done jobs"

# --- a changed input is redone; a task killed half-way leaves nothing that looks done
cp "$W/in/c.slcap" "$W/in/b.slcap"  # b's content changes (now c's frames)
"$SLSCAN" -q reprocess "$W/in/b.slcap" --calib "$CAL" --config "$CFG" --out "$W/local/b2" || fail "local reprocess of b"
"$SLSCAN" -q batch plan "$W/in/a.slcap" "$W/in/b.slcap" "$W/in/c.slcap" "$W/in/d.slcap" --calib "$CAL" \
  --config "$CFG" --out "$ROOT" || fail "third plan"
grep -q -- '--array=1,3$' "$ROOT/batch.sbatch" || fail "changed b not planned again: $(grep array "$ROOT/batch.sbatch")"
job=$(sbatch --parsable --array=1 "$ROOT/batch.sbatch") || fail "sbatch"
job=${job%%;*}
for _ in $(seq 1 1200); do [ -s "$ROOT/jobs/1/running.json" ] && break; sleep 0.05; done
[ -s "$ROOT/jobs/1/running.json" ] || fail "task 1 did not start"
# Freeze the task at once (its reprocess takes about a second), so the kill is surely half-way.
task_pid=$(sed -nE 's/.*"pid": ([0-9]+).*/\1/p' "$ROOT/jobs/1/running.json")
[ -n "$task_pid" ] && kill -STOP "$task_pid" 2>/dev/null
[ ! -e "$ROOT/jobs/1/done.json" ] || fail "task 1 finished before it could be killed"
scancel --signal=KILL --full "$job"
for _ in $(seq 1 60); do [ -z "$(squeue -h)" ] && break; sleep 0.5; done
[ ! -e "$ROOT/jobs/1/done.json" ] && [ ! -e "$ROOT/jobs/1/out" ] || fail "the killed task left something that looks done"
"$SLSCAN" batch status "$ROOT" | tee "$W/status2.txt"
grep -q "1 pending .*b.slcap" "$W/status2.txt" || fail "the killed task is not pending"
submit --array=1
same_outputs "$W/local/b2" "$ROOT/jobs/1/out"
"$SLSCAN" batch status "$ROOT" | tee "$W/status3.txt"
grep -q "4 jobs: 3 done, 1 failed" "$W/status3.txt" || fail "final status"
phase "PASS"
