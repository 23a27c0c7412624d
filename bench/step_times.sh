#!/usr/bin/env bash
# Joint-step times of `qdo design` for the sweep cost model (BENCHMARKS.md, "Sweeps on several
# ranks and the cost of the paper's grid"): the median `step_s` of the log after the first WARM
# steps, for the small preset with the default Res-UNet, the paper preset with the paper's Res-UNet
# (resunet:paper, depth 7, root 32) and the paper preset with the Wiener decoder. Synthetic
# training scenes (the paper preset's 512 x 512 patches need no data files). Prints one markdown
# row per case and writes OUT/step_times.csv.
#
# Usage: bench/step_times.sh OUT [STEPS=20] [WARM=5]   (env: QDO=./build/qdo; QDO_TORCH_DEVICE=cuda
#        for the network on a GPU; CASES="small-resunet paper-resunet paper-wiener")
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: bench/step_times.sh OUT [STEPS] [WARM]}
STEPS=${2:-20}
WARM=${3:-5}
QDO=${QDO:-./build/qdo}
mkdir -p "$OUT"
echo "case,preset,decoder,steps,median_step_s,q25_step_s,q75_step_s,whole_command_s" > "$OUT/step_times.csv"
for c in ${CASES:-small-resunet paper-resunet paper-wiener}; do
  case $c in
    small-resunet) preset=small; dec=resunet ;;
    paper-resunet) preset=paper; dec=resunet:paper ;;
    paper-wiener) preset=paper; dec=wiener ;;
    *) echo "step_times: unknown case $c" >&2; exit 2 ;;
  esac
  run="$OUT/run_$c"
  rm -rf "$run"
  t0=$(date +%s.%N)
  "$QDO" design --recipe qdo --preset "$preset" --decoder "$dec" --mode qdo+a --levels 4 --epochs 1 --steps-per-epoch "$STEPS" \
    --seed 0 --out "$run" > "$OUT/$c.log" 2>&1 || { tail -20 "$OUT/$c.log"; exit 1; }
  t1=$(date +%s.%N)
  python3 - "$run/log.csv" "$c" "$preset" "$dec" "$WARM" "$(python3 -c "print($t1 - $t0)")" "$OUT/step_times.csv" <<'PY'
import csv, statistics, sys
log, case, preset, dec, warm, whole, out = sys.argv[1:8]
rows = list(csv.DictReader(l for l in open(log) if not l.startswith('#')))
t = sorted(float(r["step_s"]) for r in rows[int(warm):])
q = statistics.quantiles(t, n=4) if len(t) > 1 else [t[0]] * 3
print("| %s | %s | %s | %d | %.4f | [%.4f, %.4f] | %.1f |" % (case, preset, dec, len(t), statistics.median(t), q[0], q[2], float(whole)))
open(out, "a").write("%s,%s,%s,%d,%.5f,%.5f,%.5f,%.2f\n" % (case, preset, dec, len(t), statistics.median(t), q[0], q[2], float(whole)))
PY
done
