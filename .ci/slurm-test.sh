#!/usr/bin/env bash
# A sharded experiment on a real Slurm: installs Debian's slurm-wlm and munge (if missing),
# starts a one-node cluster on this machine (munged, slurmctld, slurmd, all in a temporary
# folder, on free ports), submits the job array and the merge job that
# `onsager experiment slurm` writes for a --quick experiment in 3 shards, waits for the merge,
# and checks the merged results.csv and summary.json against an unsharded local run (timing
# columns aside). Every daemon it started is stopped by its process id on exit.
#
# Needs root (slurmd starts the jobs as their user) and apt-get when the packages are missing.
# Environment: ONSAGER_BIN (default target/release/onsager, built if missing or stale),
# ONSAGER_SLURM_EXPERIMENT (default tanh-limits), ONSAGER_SLURM_TIMEOUT (seconds to wait for
# the jobs, default 240), ONSAGER_SLURM_KEEP=1 keeps the temporary folder.
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$(pwd)
experiment=${ONSAGER_SLURM_EXPERIMENT:-tanh-limits}
timeout_s=${ONSAGER_SLURM_TIMEOUT:-240}
shards=3
start=$SECONDS

say() { echo "[slurm-test $((SECONDS - start))s] $*"; }
fail() {
  say "FAIL: $*"
  exit 1
}

if [ "$(id -u)" -ne 0 ]; then
  fail "must run as root (slurmd runs the jobs as the submitting user)"
fi

# --- packages -----------------------------------------------------------------------------
missing=()
for p in slurm-wlm munge; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  say "apt-get install ${missing[*]}"
  # No service may start during the installation: this script starts its own daemons.
  policy=/usr/sbin/policy-rc.d
  made_policy=0
  if [ ! -e "$policy" ]; then
    printf '#!/bin/sh\nexit 101\n' >"$policy"
    chmod 755 "$policy"
    made_policy=1
  fi
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  if [ "$made_policy" = 1 ]; then rm -f "$policy"; fi
else
  say "slurm-wlm and munge already installed"
fi
say "$(slurmctld -V), $(munged -V 2>&1 | awk '{print $1; exit}')"

# --- the binary ---------------------------------------------------------------------------
# The release binary `cargo test --workspace --release` leaves (a `cargo build` after it would
# compile again), built when missing or older than the sources; ONSAGER_BIN overrides it.
bin=${ONSAGER_BIN:-$repo/target/release/onsager}
if [ -z "${ONSAGER_BIN:-}" ] && { [ ! -x "$bin" ] ||
  [ -n "$(find src closures Cargo.toml Cargo.lock experiments -newer "$bin" -print -quit)" ]; }; then
  say "cargo build --release --bin onsager"
  cargo build --release --quiet --bin onsager
fi
[ -x "$bin" ] || fail "no onsager binary at $bin"

# --- the cluster --------------------------------------------------------------------------
work=$(mktemp -d /tmp/onsager-slurm.XXXXXX)
chmod 700 "$work"
pids=()
jobs_submitted=()
cleanup() {
  local status=$?
  set +e
  if [ ${#jobs_submitted[@]} -gt 0 ] && [ -n "${SLURM_CONF:-}" ]; then
    timeout 10 scancel "${jobs_submitted[@]}" 2>/dev/null
  fi
  # Stop the daemons in reverse order of their start, by process id.
  local i pid
  for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
    pid=${pids[$i]}
    kill "$pid" 2>/dev/null || continue
    for _ in $(seq 50); do
      kill -0 "$pid" 2>/dev/null || break
      sleep 0.1
    done
    kill -9 "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
  done
  if [ "$status" -ne 0 ]; then
    for log in slurmctld.log slurmd.log munged.log; do
      [ -f "$work/$log" ] && { echo "--- tail of $log"; tail -n 30 "$work/$log"; }
    done
  fi
  if [ "$status" -eq 0 ] && [ "${ONSAGER_SLURM_KEEP:-0}" != 1 ]; then
    rm -rf "$work"
  else
    echo "[slurm-test] files kept in $work"
  fi
  exit "$status"
}
trap cleanup EXIT

# Two free TCP ports on 127.0.0.1 (so that another cluster on this machine is not disturbed).
port_free() { ! (echo >"/dev/tcp/127.0.0.1/$1") 2>/dev/null; }
ports=()
for p in $(seq 16817 16999); do
  port_free "$p" && ports+=("$p")
  [ ${#ports[@]} -eq 2 ] && break
done
[ ${#ports[@]} -eq 2 ] || fail "no free ports in 16817-16999"

host=$(hostname -s)
cpus=$(nproc)
mkdir -p "$work/state" "$work/spool" "$work/munge"
chmod 700 "$work/munge"
dd if=/dev/urandom of="$work/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$work/munge/munge.key"
socket=$work/munge/munge.socket
export SLURM_CONF=$work/slurm.conf
cat >"$SLURM_CONF" <<EOF
ClusterName=onsager-test
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=${ports[0]}
SlurmdPort=${ports[1]}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$socket
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
SchedulerType=sched/backfill
ReturnToService=2
MpiDefault=none
SwitchType=switch/none
MinJobAge=600
MailProg=/bin/true
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=test Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF

munged --foreground --force --socket="$socket" --key-file="$work/munge/munge.key" \
  --pid-file="$work/munged.pid" --log-file="$work/munged.log" --seed-file="$work/munge/seed" \
  >>"$work/munged.log" 2>&1 &
pids+=($!)
for _ in $(seq 50); do [ -S "$socket" ] && break; sleep 0.1; done
[ -S "$socket" ] || fail "munged did not open $socket"
say "munged pid ${pids[-1]}"

slurmctld -D -c -i -f "$SLURM_CONF" >>"$work/slurmctld.out" 2>&1 &
pids+=($!)
say "slurmctld pid ${pids[-1]} (port ${ports[0]})"
slurmd -D -f "$SLURM_CONF" >>"$work/slurmd.out" 2>&1 &
pids+=($!)
say "slurmd pid ${pids[-1]} (port ${ports[1]})"

# Wait until the node is idle.
deadline=$((SECONDS + 60))
until state=$(timeout 5 sinfo -h -n "$host" -o %T 2>/dev/null) && [ "$state" = idle ]; do
  [ $SECONDS -lt $deadline ] || fail "node $host not idle after 60 s (state: ${state:-no answer})"
  for pid in "${pids[@]}"; do kill -0 "$pid" 2>/dev/null || fail "daemon $pid ended"; done
  sleep 0.5
done
say "node $host idle: $(sinfo -h -o '%P %D %c %T')"

# --- the sharded run on Slurm -------------------------------------------------------------
job_state() {
  timeout 10 scontrol -o show job "$1" 2>/dev/null | sed -n 's/.* JobState=\([A-Z_]*\) .*/\1/p' | head -1
}
# Waits for job $1 to complete; fails if it ends otherwise or takes more than the timeout.
wait_for() {
  local state deadline=$((SECONDS + timeout_s))
  while :; do
    state=$(job_state "$1")
    case "$state" in
      COMPLETED) return 0 ;;
      FAILED | CANCELLED | TIMEOUT | NODE_FAIL | OUT_OF_MEMORY | BOOT_FAIL | DEADLINE | PREEMPTED)
        show_jobs "$@"
        fail "job $1 ended $state" ;;
    esac
    [ $SECONDS -lt $deadline ] || fail "job $1 not done after $timeout_s s (state: ${state:-unknown})"
    sleep 1
  done
}
# One line per job (each array task its own) with its state and exit code.
show_jobs() {
  local j
  for j in "$@"; do timeout 10 scontrol -o show job "$j"; done |
    while read -r line; do
      echo "$line" | grep -oE '^JobId=[0-9]+|(ArrayJobId|ArrayTaskId|JobName|JobState|Reason|ExitCode|RunTime|Dependency)=[^ ]*' |
        paste -sd' '
    done | sort -u
}

out=$work/out
"$bin" experiment slurm "$experiment" --quick --shards "$shards" --cpus-per-task 1 \
  --time 10:00 --partition test --out "$out"
sub=$(sh "$out/slurm/submit.sh")
echo "$sub"
array=$(echo "$sub" | sed -n 's/^array job \([0-9]*\) .*/\1/p')
merge=$(echo "$sub" | sed -n 's/.*merge job \([0-9]*\)$/\1/p')
[ -n "$array" ] && [ -n "$merge" ] || fail "submit.sh printed no job ids"
jobs_submitted+=("$array" "$merge")

# The unsharded local run to compare with, while the cluster works.
"$bin" experiment run "$experiment" --quick --jobs 1 --out "$work/local" >"$work/local.log" 2>&1 ||
  { cat "$work/local.log"; fail "the unsharded run failed"; }

wait_for "$merge" "$array"
say "array job $array and merge job $merge done; scontrol show job:"
show_jobs "$array" "$merge"
for log in "$out"/slurm/shard-*.log "$out/slurm/merge.log"; do
  echo "--- $log"
  cat "$log"
done

# --- merged = unsharded -------------------------------------------------------------------
# The rows without solve_seconds (the 7th column), sorted; summary.json without the
# solve_seconds statistics.
rows() {
  tail -n +2 "$1" |
    sed -E 's/^("[^"]*"|[^,]*),([^,]*),([^,]*),([^,]*),([^,]*),([^,]*),[^,]*,/\1,\2,\3,\4,\5,\6,/' | sort
}
summary() { awk '/"solve_seconds": \{/ { skip = 1 } skip { if ($0 ~ /\}/) skip = 0; next } { print }' "$1"; }
check_merged() {
  local n f
  for f in "$work/local/results.csv" "$out/results.csv"; do
    [ "$(head -1 "$f" | cut -d, -f7)" = solve_seconds ] || fail "$f: the 7th column is not solve_seconds"
  done
  n=$(tail -n +2 "$out/results.csv" | wc -l)
  [ "$n" -gt 0 ] || fail "the merged results.csv has no rows"
  diff <(rows "$work/local/results.csv") <(rows "$out/results.csv") ||
    fail "the merged results.csv differs from the unsharded run's"
  diff <(summary "$work/local/summary.json") <(summary "$out/summary.json") ||
    fail "the merged summary.json differs from the unsharded run's"
  say "merged = unsharded: $n rows (timing column aside), summary.json identical (timings aside)"
}
check_merged

# --- a task resubmitted after losing rows -------------------------------------------------
# Shard 1 as a task killed while writing leaves it: its first data row and half of the next.
shard1=$out/shards/1-of-$shards/results.csv
head -2 "$shard1" >"$work/cut.csv"
sed -n 3p "$shard1" | head -c 20 >>"$work/cut.csv"
cp "$work/cut.csv" "$shard1"
sbatch_out=$(sbatch --parsable --array=1 "$out/slurm/array.sbatch")
again=${sbatch_out%%;*}
jobs_submitted+=("$again")
sbatch_out=$(sbatch --parsable --dependency="afterok:$again" --kill-on-invalid-dep=yes "$out/slurm/merge.sbatch")
merge_again=${sbatch_out%%;*}
jobs_submitted+=("$merge_again")
say "resubmitted shard 1 (sbatch --array=1): job $again, merge job $merge_again"
wait_for "$merge_again" "$again"
show_jobs "$again" "$merge_again"
tail -n 4 "$out/slurm/shard-1.log"
tail -n 4 "$out/slurm/merge.log"
grep -q "kept 1 rows of the earlier run" "$out/slurm/shard-1.log" ||
  fail "the resubmitted shard did not keep its complete row"
check_merged
say "PASS: $experiment --quick in $shards shards on Slurm, merged, one shard resubmitted, merged again"
