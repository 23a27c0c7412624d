#!/usr/bin/env bash
# A real Slurm job array over `qdo sweep --cell slurm`, on a one-node cluster
# this script starts for itself from Debian's slurm-wlm and munge: munged, slurmctld and slurmd
# with a private configuration, state and ports under a scratch folder, run as root (as CI runs).
# It submits the sweep's cells as `sbatch --array=0-(N-1)`, waits for the array, collects the
# tables with `qdo sweep --collect`, and compares them with the same sweep run serially. It stops
# the daemons it started and removes its scratch folder, whatever happens.
#
# Usage: scripts/test_slurm.sh BUILD_DIR      (CTest entry "slurm", label slurm: ctest -L slurm)
# Exit 0 when the tables agree, 1 when they do not or the cluster does not come up, 77 (skipped)
# when slurm-wlm or munge is not installed (apt-get install slurm-wlm) or not run as root.
set -euo pipefail
build=$(cd "${1:?usage: scripts/test_slurm.sh BUILD_DIR}" && pwd)
qdo="$build/qdo"
for b in slurmctld slurmd sbatch squeue munged munge; do
  command -v "$b" > /dev/null || { echo "test_slurm: $b not installed (apt-get install slurm-wlm): skipped"; exit 77; }
done
[ "$(id -u)" -eq 0 ] || { echo "test_slurm: needs root (it starts munged and slurmd): skipped"; exit 77; }
id munge > /dev/null 2>&1 || { echo "test_slurm: no munge user (apt-get install munge): skipped"; exit 77; }

dir=$(mktemp -d /tmp/qdo_slurm_XXXXXX)
chmod 755 "$dir"  # munged runs as the munge user and must reach its folder
cleanup() {
  # The daemons this script started (their pid files), asked to stop, then killed after 10 s.
  local started=()
  for f in slurmctld.pid slurmd.pid munge/munged.pid; do
    [ -f "$dir/$f" ] && started+=("$(cat "$dir/$f")")
  done
  for p in "${started[@]}"; do kill "$p" 2> /dev/null || true; done
  for _ in $(seq 20); do
    alive=0
    for p in "${started[@]}"; do kill -0 "$p" 2> /dev/null && alive=1; done
    [ "$alive" -eq 0 ] && break
    sleep 0.5
  done
  for p in "${started[@]}"; do kill -9 "$p" 2> /dev/null || true; done
  rm -rf "$dir"
}
trap cleanup EXIT
mkdir -p "$dir/state" "$dir/spool" "$dir/log" "$dir/munge"
chown munge:munge "$dir/munge"
chmod 755 "$dir/munge"  # munged wants execute for all on its socket folder
# munged with its own socket (slurm finds it through AuthInfo); the key of the munge package.
[ -f /etc/munge/munge.key ] || { echo "test_slurm: /etc/munge/munge.key missing"; exit 1; }
runuser -u munge -- munged --socket="$dir/munge/socket" --log-file="$dir/munge/munged.log" \
  --pid-file="$dir/munge/munged.pid" --seed-file="$dir/munge/seed" || { cat "$dir/munge/munged.log"; exit 1; }
host=$(hostname -s)
# Ports from the process id, so that two runs (or a system Slurm) do not collide.
port=$(( 20000 + ($$ % 20000) ))
cat > "$dir/slurm.conf" << EOF
ClusterName=qdotest
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
SlurmctldPort=$port
SlurmdPort=$(( port + 1 ))
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName=$host CPUs=$(nproc) State=UNKNOWN
PartitionName=qdo Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$dir/slurm.conf"
slurmctld -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
for _ in $(seq 30); do
  sinfo -h -o '%T' 2> /dev/null | grep -q idle && break
  sleep 1
done
sinfo -h -o '%T' | grep -q idle || { echo "test_slurm: the one-node cluster did not come up"; tail -n 20 "$dir"/log/*.log; exit 1; }

# The grid: 2 seeds x (full, do, qdo, qdo+a) at 2 levels, 6 runs of 12 steps on a 32 x 32 DOE.
"$qdo" config --preset small > "$dir/small.json"
python3 - "$dir/small.json" "$dir/cfg.json" << 'PY'
import json, sys
c = json.load(open(sys.argv[1]))
n, b = 32, 3
c.update({"n": n, "padding_px": n // 4, "bands": b, "wavelength_start_nm": 450, "wavelength_step_nm": 50.0,
          "sensor_distance_m": 0.0125 * n / 256, "srf_interpolate": True})
json.dump(c, open(sys.argv[2], "w"), indent=1)
PY
args=(--config "$dir/cfg.json" --grid levels=2 --grid mode=do,qdo,qdo+a --grid seed=5,6 --epochs 4 --steps-per-epoch 3
      --t0 1 --t1 3 --synthetic-scenes 3 --eval-scenes 2)
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$build/kernel-cache}" QDO_DEVICE="${QDO_DEVICE:-cpu}"
"$qdo" sweep "${args[@]}" --out "$dir/serial" > "$dir/serial.log" 2>&1 || { cat "$dir/serial.log"; exit 1; }
cells=$("$qdo" sweep "${args[@]}" --plan --out "$dir/array" | grep -c '^[0-9]')
printf -v cmd '%q ' "$qdo" sweep "${args[@]}" --cell slurm --out "$dir/array"
job=$(sbatch --parsable --array=0-$(( cells - 1 )) --ntasks=1 --cpus-per-task=1 -o "$dir/log/cell-%a.log" --wrap "$cmd")
echo "test_slurm: job array $job of $cells cells submitted"
for _ in $(seq 600); do
  [ -z "$(squeue -h -j "$job" 2> /dev/null)" ] && break
  sleep 1
done
[ -z "$(squeue -h -j "$job")" ] || { echo "test_slurm: the array did not finish in 600 s"; squeue; exit 1; }
ran=$(cat "$dir"/log/cell-*.log | grep -c '^\[sweep\] cell #' || true)
echo "test_slurm: $ran cell lines in the array's logs"
[ "$ran" -eq "$cells" ] || { echo "test_slurm: expected $cells cells run by the array"; tail -n 5 "$dir"/log/cell-*.log; exit 1; }
"$qdo" sweep "${args[@]}" --collect --out "$dir/array" > "$dir/collect.log" 2>&1 || { cat "$dir/collect.log"; exit 1; }
# The tables without their `inputs` column (a hash of paths: the folders differ); values to 1e-9 relative.
python3 - "$dir/serial" "$dir/array" << 'PY'
import csv, math, sys
a, b = sys.argv[1], sys.argv[2]
bad = 0
for name in ("table1.csv", "table2.csv", "table1_seeds.csv", "comparisons.csv"):
    ra = list(csv.DictReader(open(f"{a}/{name}")))
    rb = list(csv.DictReader(open(f"{b}/{name}")))
    if len(ra) != len(rb) or (ra and ra[0].keys() != rb[0].keys()):
        print(f"test_slurm: {name}: other rows or columns"); bad += 1; continue
    for x, y in zip(ra, rb):
        for k in x:
            if k == "inputs": continue
            try:
                u, v = float(x[k]), float(y[k])
                same = (math.isnan(u) and math.isnan(v)) or abs(u - v) <= 1e-9 * max(1.0, abs(u))
            except ValueError:
                same = x[k] == y[k]
            if not same:
                print(f"test_slurm: {name} {k}: serial {x[k]}, array {y[k]}"); bad += 1
print(f"test_slurm: the job array's tables {'equal' if not bad else 'differ from'} the serial sweep's")
sys.exit(1 if bad else 0)
PY
