#!/usr/bin/env bash
# A real Slurm run of `softdiff sweep --slurm` (docs/cli.md "sweep and collect"): a one-node Slurm
# on localhost started here (Debian's munge and slurm-wlm: munged with a generated key,
# slurmctld and slurmd with a generated slurm.conf, everything in a temporary folder,
# free ports), a 4-job array of 2-step beam runs submitted with --jobs 2 (%2), waited
# for, collected, and every job's trajectory compared with the same job run directly
# with the same --threads (identical datasets). Every daemon started here is stopped
# by its PID on exit. Runs as root (CI) or as the current user (SlurmUser).
#
#   tests/app/sweep_slurm.sh SOURCE_DIR SOFTDIFF_BINARY
set -euo pipefail
src=$1
softdiff=$2
fail() { echo "sweep_slurm: FAIL: $*" >&2; exit 1; }
for p in munged mungekey slurmctld slurmd sbatch squeue parallel; do
  command -v "$p" >/dev/null || PATH="$PATH:/usr/sbin" command -v "$p" >/dev/null ||
    fail "$p is not installed (Debian's munge, slurm-wlm and parallel: scripts/setup installs them)"
done
export PATH="$PATH:/usr/sbin"

tmp=$(mktemp -d /tmp/softdiff_slurm.XXXXXX)
chmod 755 "$tmp"
pids=()
cleanup() {
  local rc=$? pid
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  for pid in "${pids[@]}"; do
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$pid" 2>/dev/null || true
  done
  if ((rc != 0)); then
    for log in "$tmp"/*.log; do [[ -f $log ]] && { echo "--- $log" >&2; tail -n 30 "$log" >&2; }; done
  fi
  rm -rf "$tmp"
}
trap cleanup EXIT
start=$(date +%s.%N)

# Two free TCP ports for slurmctld and slurmd.
read -r port_ctld port_d < <(/usr/bin/python3 -c '
import socket
s = [socket.socket() for _ in range(2)]
for x in s: x.bind(("127.0.0.1", 0))
print(*[x.getsockname()[1] for x in s])')

# munged: its own key, socket, pid, log and seed in $tmp.
mkdir -m 755 "$tmp/munge"
mungekey --create --keyfile="$tmp/munge/munge.key" --bits=1024
chmod 400 "$tmp/munge/munge.key"
munged --foreground --force --key-file="$tmp/munge/munge.key" --socket="$tmp/munge/munge.socket" \
  --pid-file="$tmp/munge/munged.pid" --log-file="$tmp/munged.log" --seed-file="$tmp/munge/munge.seed" \
  --num-threads=2 >"$tmp/munged.out.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do [[ -S $tmp/munge/munge.socket ]] && break; sleep 0.1; done
[[ -S $tmp/munge/munge.socket ]] || fail "munged did not start"

user=$(id -un)
node=$(hostname -s)
cpus=$(nproc)
mkdir -p "$tmp/state" "$tmp/spool"
cat > "$tmp/slurm.conf" <<EOF
ClusterName=softdiff-test
SlurmctldHost=$node(127.0.0.1)
SlurmUser=$user
SlurmdUser=$user
SlurmctldPort=$port_ctld
SlurmdPort=$port_d
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$tmp/munge/munge.socket
StateSaveLocation=$tmp/state
SlurmdSpoolDir=$tmp/spool
SlurmctldPidFile=$tmp/slurmctld.pid
SlurmdPidFile=$tmp/slurmd.pid
SlurmctldLogFile=$tmp/slurmctld.log
SlurmdLogFile=$tmp/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
SchedulerType=sched/builtin
SwitchType=switch/none
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
ReturnToService=2
SlurmdTimeout=30
InactiveLimit=0
KillWait=5
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=test Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF=$tmp/slurm.conf
slurmctld -D -i -f "$SLURM_CONF" >"$tmp/slurmctld.out.log" 2>&1 &
pids+=($!)
slurmd -D -f "$SLURM_CONF" -N "$node" >"$tmp/slurmd.out.log" 2>&1 &
pids+=($!)
ready=""
for _ in $(seq 150); do
  if sinfo -h -N -o '%T' 2>/dev/null | grep -qx 'idle'; then ready=1; break; fi
  sleep 0.2
done
[[ -n $ready ]] || fail "the Slurm node did not become idle in 30 s (sinfo: $(sinfo -N 2>&1 | tr '\n' ' '))"
echo "sweep_slurm: Slurm up after $(/usr/bin/python3 -c "import time; print('%.1f' % (time.time() - $start))") s" >&2

# The sweep: 4 jobs of the shipped beam, 2 steps each.
work=$tmp/work
mkdir -p "$work"
cat > "$work/beam.yaml" <<EOF
softdiff: 1
simulation: {dt: 0.01, steps: 2}
bodies:
  - name: beam
    mesh: $src/meshes/beam.msh
    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}
    fixed:
      - group: clamp
    effectors:
      - {name: tip, point: [0.2, 0.01, 0.01]}
output: {fields: [x, effectors]}
EOF
cat > "$work/s.yaml" <<'EOF'
softdiff_sweep: 1
scene: beam.yaml
command: simulate
grid:
  bodies.beam.material.young: [1.0e6, 2.0e6]
  bodies.beam.material.poisson: [0.3, 0.45]
EOF
cd "$work"
job=$("$softdiff" sweep s.yaml -o out --slurm --jobs 2 --quiet)
[[ $job =~ ^[0-9]+$ ]] || fail "sweep --slurm printed '$job', not a job id"
grep -qx '#SBATCH --array=0-3%2' out/sweep.sbatch || fail "out/sweep.sbatch: no --array=0-3%2: $(cat out/sweep.sbatch)"
done_=""
for _ in $(seq 600); do
  if [[ -z $(squeue -h -j "$job" 2>/dev/null) ]]; then done_=1; break; fi
  sleep 0.2
done
[[ -n $done_ ]] || fail "the array $job did not finish in 120 s: $(squeue 2>&1 | tr '\n' ' ')"
ls out/slurm-"$job"_*.out >/dev/null || fail "no Slurm task output (out/slurm-${job}_*.out)"

"$softdiff" collect out --quiet || fail "collect: exit $? (not every job complete): $(cat out/results.csv)"
[[ $(wc -l < out/results.csv) -eq 5 ]] || fail "results.csv: $(cat out/results.csv)"

# Each job against the same command run directly with the same --threads (and
# OpenBLAS threads, as the job line sets them).
threads=$(grep -o -- '--threads [0-9]*' out/jobs.txt | head -1 | cut -d' ' -f2)
[[ $threads == 1 ]] || fail "--slurm without --cpus-per-task: 1 thread a job, got $threads"
id=0
for young in 1.0e6 2.0e6; do
  for poisson in 0.3 0.45; do
    OPENBLAS_NUM_THREADS=$threads "$softdiff" simulate beam.yaml --set bodies.beam.material.young=$young \
      --set bodies.beam.material.poisson=$poisson --threads "$threads" -o direct_$id.h5 --quiet
    /usr/bin/python3 - out/$id.h5 direct_$id.h5 <<'PY' || fail "job $id differs from the direct run"
import sys, h5py, numpy as np
a, b = (h5py.File(f, "r") for f in sys.argv[1:3])
assert a.attrs["status"] == "complete", a.attrs["status"]
for d in ("/time", "/bodies/beam/x", "/bodies/beam/effectors/tip"):
    assert np.array_equal(a[d][()], b[d][()]), d
PY
    id=$((id + 1))
  done
done
echo "sweep_slurm: OK: 4 jobs through Slurm array $job, identical to direct runs ($(/usr/bin/python3 -c "import time; print('%.1f' % (time.time() - $start))") s)" >&2
