#!/usr/bin/env bash
# Speed of `qdo calibrate`: one calibration of a 31-frame monochromator sweep (16-bit
# RGGB 12-bit frames made by `qdo simulate --capture psf-sweep` of a lens at the given preset, plus
# 8 darks), REPEATS runs after one warm-up; the median and min..max of every step the command
# reports (calibrate.hpp's steps) and of the whole command's wall time (writing psf.h5 and psf.png
# included). Baseline in the same run: reading the 39 PNG files alone (`qdo calibrate` steps
# "match" + "read" are that; the whole-command time against them shows the processing's share).
# Usage: bench/bench_calibrate.sh [PRESET=small|paper] [REPEATS=5]
set -euo pipefail
cd "$(dirname "$0")/.."
PRESET=${1:-small}
REPEATS=${2:-5}
QDO=${QDO:-build/qdo}
export QDO_DEVICE=${QDO_DEVICE:-cpu} QDO_CACHE_DIR=${QDO_CACHE_DIR:-$PWD/build/kernel-cache}
W=$(mktemp -d)
trap 'rm -rf "$W"' EXIT
"$QDO" config --preset "$PRESET" | python3 -c '
import json, sys
c = json.load(sys.stdin)
c.update({"cfa": "rggb", "bit_depth": 12, "black_level_dn": 64, "read_noise_sigma": 0.001, "full_well_photons": 20000})
print(json.dumps(c))' > "$W/cam.json"
"$QDO" simulate --config "$W/cam.json" --design lens:550 --capture psf-sweep --darks 8 --out "$W/sweep" > /dev/null
for k in $(seq 0 "$REPEATS"); do
  rm -rf "$W/cal"
  t0=$(date +%s.%N)
  "$QDO" calibrate --config "$W/cam.json" --frames "$W/sweep/frames" --darks "$W/sweep/darks" --out "$W/cal" > "$W/log_$k.txt"
  t1=$(date +%s.%N)
  echo "[whole command] $(echo "$t1 - $t0" | bc)" >> "$W/log_$k.txt"
done
python3 - "$W" "$REPEATS" "$PRESET" "$(cat /proc/cpuinfo | grep -m1 'model name' | cut -d: -f2)" <<'PY'
import re, statistics, sys
w, repeats, preset, cpu = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4].strip()
steps = {}
frame = ""
for k in range(1, repeats + 1):  # run 0 is the warm-up
    text = open(f"{w}/log_{k}.txt").read()
    frame = re.search(r"of (\d+ x \d+), S = (\d+)", text).group(0)
    for name, sec in re.findall(r"\[([^\]]+)\] ([0-9.]+)", text):
        steps.setdefault(name, []).append(float(sec))
print(f"qdo calibrate, preset {preset}: 31 frames + 8 darks, frames {frame}; {repeats} runs after 1 warm-up; {cpu}")
print("| step | median s | min..max s |")
print("|---|---:|---|")
for name, v in steps.items():
    print(f"| {name} | {statistics.median(v):.4f} | {min(v):.4f}..{max(v):.4f} |")
PY
