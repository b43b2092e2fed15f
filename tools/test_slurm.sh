#!/usr/bin/env bash
# The batch on a real Slurm (run by tools/test.sh): starts a one-node cluster on this
# machine (munged with a key of its own, slurmctld and slurmd, in a temporary folder,
# on ports of their own), submits a small manifest with `dopslam batch --slurm
# --submit` (3 array tasks, 6 short deterministic runs), waits for the collection job,
# checks the collected tables against a single-process batch of the same manifest, and
# stops the daemons it started, by their pid files.
#
#   bash tools/test_slurm.sh [DOPSLAM]     # default ./target/release/dopslam
#
# Needs root and Debian's slurm-wlm and munge (installed when missing). Where the
# daemons cannot start it says why and fails; DOPSLAM_SKIP_SLURM=1 skips it explicitly.
set -euo pipefail
cd "$(dirname "$0")/.."
say() { printf '\033[1m[slurm test]\033[0m %s\n' "$*"; }
if [ "${DOPSLAM_SKIP_SLURM:-0}" = 1 ]; then
    say "skipped (DOPSLAM_SKIP_SLURM=1)"
    exit 0
fi
bin=$(realpath "${1:-./target/release/dopslam}")
[ -x "$bin" ] || { say "FAIL: no dopslam binary at $bin (build first)"; exit 1; }
[ "$(id -u)" = 0 ] || { say "FAIL: needs root to start slurmctld, slurmd and munged (DOPSLAM_SKIP_SLURM=1 skips)"; exit 1; }
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    say "installing slurm-wlm and munge (Debian)"
    { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null; } \
        || { say "FAIL: apt-get could not install slurm-wlm and munge"; exit 1; }
fi
started=$(date +%s)
dir=$(mktemp -d /tmp/dopslam-slurm.XXXXXX)
chmod 755 "$dir"
host=$(hostname -s)
cpus=$(nproc)
memory=$(( $(awk '/MemTotal/ {print int($2 / 1024)}' /proc/meminfo) - 1024 ))
mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
stop() {
    for pidfile in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
        if [ -s "$pidfile" ]; then kill "$(cat "$pidfile")" 2>/dev/null || true; fi
    done
    sleep 1
}
fail() {
    say "FAIL: $*"
    for log in slurmctld.log slurmd.log munge/munged.log; do
        [ -f "$dir/$log" ] && { echo "--- $log"; tail -15 "$dir/$log"; }
    done
    stop
    exit 1
}
trap stop EXIT

# munge: a key of its own, its own socket.
dd if=/dev/urandom bs=1 count=1024 of="$dir/munge/munge.key" status=none
chmod 400 "$dir/munge/munge.key"
munged --force --key-file="$dir/munge/munge.key" --socket="$dir/munge/munge.socket" \
    --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" \
    --seed-file="$dir/munge/munged.seed" || fail "munged did not start"

cat > "$dir/slurm.conf" <<EOF
ClusterName=dopslamtest
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/munge.socket
CredType=cred/munge
SlurmctldPort=16817
SlurmdPort=16818
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
MpiDefault=none
NodeName=$host CPUs=$cpus RealMemory=$memory State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$dir/slurm.conf
slurmctld -f "$SLURM_CONF" || fail "slurmctld did not start"
slurmd -f "$SLURM_CONF" || fail "slurmd did not start"
for _ in $(seq 60); do
    state=$(sinfo -h -N -o '%T' 2>/dev/null | head -1 || true)
    [ "$state" = idle ] && break
    sleep 1
done
[ "$state" = idle ] || fail "the node never became idle (sinfo: ${state:-no answer})"
say "cluster up: $(sinfo -h -o '%P %a %D %T %c cpus %m MB')"

# A small manifest: 2 synthetic sequences x 3 modes, 30 frames, deterministic.
work=$dir/work
mkdir -p "$work"
cat > "$work/study.toml" <<EOF
[batch]
modes = ["dop", "no-dop", "mask-boxes"]
deterministic = true
detections = "oracle"
dense = false
cores_per_run = 1
memory_per_run_gib = 1.0

[[sequence]]
preset = "$PWD/configs/synth/static_room.toml"
synth_frames = 30

[[sequence]]
preset = "$PWD/configs/synth/demo_walking.toml"
synth_frames = 30
seeds = [4]
EOF
export DOPSLAM_DATA=$PWD/data
"$bin" batch "$work/study.toml" --out "$work/slurm-out" --slurm --submit --shards 3 --time 10:00 \
    | tee "$work/submit.txt"
collect=$(sed -n 's/.*collection job \([0-9]*\).*/\1/p' "$work/submit.txt")
array=$(sed -n 's/.*array job \([0-9]*\),.*/\1/p' "$work/submit.txt")
[ -n "$collect" ] && [ -n "$array" ] || fail "no job ids in dopslam's output"
squeue -j "$array,$collect" -o '%.10i %.22j %.8T %.10M %R' || true
for _ in $(seq 600); do
    squeue -h -j "$collect" 2>/dev/null | grep -q . || break
    sleep 1
done
squeue -h -j "$collect" 2>/dev/null | grep -q . && fail "the collection job did not end within 10 minutes"
say "jobs ended; scontrol's last word on them:"
for job in "$array" "$collect"; do
    scontrol -o show job "$job" 2>/dev/null | grep -o 'JobId=[^ ]* ArrayJobId=[^ ]*\|JobId=[^ ]*\|JobName=[^ ]*\|JobState=[^ ]*\|ExitCode=[^ ]*' | paste -sd' ' || true
done
cat "$work/slurm-out/slurm/logs/collect.out"
[ -f "$work/slurm-out/results.csv" ] || fail "the collection wrote no results.csv"
grep -q '6 of 6 runs finished (0 failed), 0 missing' "$work/slurm-out/slurm/logs/collect.out" \
    || fail "the collection did not find 6 finished runs"
# The same manifest in one process: the same table.
"$bin" batch "$work/study.toml" --out "$work/single" --quiet > /dev/null
cut -d, -f1-11,14- "$work/slurm-out/results.csv" > "$work/a.csv"
cut -d, -f1-11,14- "$work/single/results.csv" > "$work/b.csv"
diff "$work/a.csv" "$work/b.csv" > /dev/null || { diff "$work/a.csv" "$work/b.csv"; fail "the Slurm batch's table differs from the single-process one"; }
say "collected table equals the single-process batch's ($(($(wc -l < "$work/a.csv") - 1)) rows); $(( $(date +%s) - started )) s in all"
stop
trap - EXIT
rm -rf "$dir"
say "PASS"
