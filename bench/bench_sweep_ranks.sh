#!/usr/bin/env bash
# A sweep on 1 and 2 MPI ranks against the serial sweep: the whole command's
# wall time (median of REPEATS runs, each into a fresh folder, kernel cache warm), the parallel
# efficiency t(serial) / (ranks x t(ranks)), and beside each time the largest difference of its
# table1.csv / comparisons.csv numbers from the serial sweep's (0: the same tables).
# The grid: N = 128, 3 bands, levels 2 and 4, modes do, qdo, qdo+a, 2 seeds: 14 cells, 10 runs of
# EPOCHS x 5 steps each (Wiener objective, synthetic scenes).
#
# Usage: bench/bench_sweep_ranks.sh [QDO=build/qdo] [REPEATS=3] [EPOCHS=10]   Prints a markdown table.
set -euo pipefail
cd "$(dirname "$0")/.."
qdo=$(realpath "${1:-build/qdo}")
repeats=${2:-3}
epochs=${3:-10}
[ "$epochs" -ge 3 ] || { echo "bench_sweep_ranks: EPOCHS >= 3" >&2; exit 2; }
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$PWD/build/kernel-cache}" QDO_DEVICE="${QDO_DEVICE:-cpu}"
dir=$(mktemp -d /tmp/qdo_bench_sweep_XXXXXX)
trap 'rm -rf "$dir"' EXIT
"$qdo" config --preset small > "$dir/small.json"
python3 - "$dir/small.json" "$dir/cfg.json" << 'PY'
import json, sys
c = json.load(open(sys.argv[1]))
n, b = 128, 3
c.update({"n": n, "padding_px": n // 4, "bands": b, "wavelength_start_nm": 450, "wavelength_step_nm": 50.0,
          "sensor_distance_m": 0.0125 * n / 256, "srf_interpolate": True})
json.dump(c, open(sys.argv[2], "w"), indent=1)
PY
args=(--recipe qdo --config "$dir/cfg.json" --grid levels=2,4 --grid mode=do,qdo,qdo+a --grid seed=1,2 --epochs "$epochs"
      --steps-per-epoch 5 --t0 1 --t1 "$(( epochs * 3 / 4 > 2 ? epochs * 3 / 4 : 2 ))" --synthetic-scenes 4 --eval-scenes 2)
"$qdo" sweep "${args[@]}" --out "$dir/warm" > "$dir/warm.log" 2>&1 || { tail -5 "$dir/warm.log"; exit 1; }  # kernel cache, FFTW wisdom
time_one() {  # time_one OUT LAUNCH...: seconds of one whole sweep command
  local out=$1; shift
  local t0 t1
  t0=$(date +%s.%N)
  "$@" "$qdo" sweep "${args[@]}" --out "$out" > "$out.log" 2>&1 || { tail -20 "$out.log"; exit 1; }
  t1=$(date +%s.%N)
  python3 -c "print($t1 - $t0)"
}
diff_tables() {  # the largest |difference| of any number in table1.csv / comparisons.csv
  python3 - "$1" "$2" << 'PY'
import csv, sys
worst = 0.0
for name in ("table1.csv", "comparisons.csv"):
    for x, y in zip(csv.DictReader(open(f"{sys.argv[1]}/{name}")), csv.DictReader(open(f"{sys.argv[2]}/{name}"))):
        for k in x:
            if k == "inputs": continue
            try: worst = max(worst, abs(float(x[k]) - float(y[k])))
            except ValueError: pass
print("%.2g" % worst)
PY
}
declare -A times
for r in $(seq "$repeats"); do
  times[serial]+="$(time_one "$dir/serial$r") "
  times[np1]+="$(time_one "$dir/np1_$r" mpirun -np 1) "
  times[np2]+="$(time_one "$dir/np2_$r" mpirun -np 2 --oversubscribe) "
done
median() { python3 -c "import statistics,sys; print('%.2f' % statistics.median(float(x) for x in sys.argv[1:]))" $1; }
spread() { python3 -c "import sys; v=[float(x) for x in sys.argv[1:]]; print('%.2f-%.2f' % (min(v), max(v)))" $1; }
ts=$(median "${times[serial]}")
echo "| launch | ranks | median wall [s] (range of $repeats) | efficiency | max table difference from serial |"
echo "|---|---:|---:|---:|---:|"
echo "| qdo sweep | 1 | $ts ($(spread "${times[serial]}")) | 1.00 | 0 |"
for k in np1 np2; do
  n=${k#np}
  t=$(median "${times[$k]}")
  eff=$(python3 -c "print('%.2f' % ($ts / ($n * $t)))")
  echo "| mpirun -np $n qdo sweep | $n | $t ($(spread "${times[$k]}")) | $eff | $(diff_tables "$dir/serial1" "$dir/${k}_1") |"
done
