#!/usr/bin/env bash
# The whole `qdo psf` command against its own in-process compute (the target: at most 1.3 x;
# BENCHMARKS.md "CPU speed"): runs `qdo psf --preset P --design lens:550` R times after one
# warm-up, each with /usr/bin/time, and prints per run the wall time, the PSF compute time the
# command prints (compute_psf + finish), their ratio, the peak memory and the size of psf.h5,
# then the medians.
# Usage: bench/psf_command.sh [QDO_BINARY] [PRESET] [RUNS] [extra qdo psf options...]
set -euo pipefail
qdo="${1:-build/qdo}"; preset="${2:-paper}"; runs="${3:-5}"; shift $(( $# < 3 ? $# : 3 ))
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
walls=(); psfs=(); ratios=()
for i in $(seq 0 "$runs"); do
  rm -rf "$work/out"
  /usr/bin/time -f "%e %M" -o "$work/time" "$qdo" psf --preset "$preset" --design lens:550 --out "$work/out" "$@" > "$work/log" 2>&1
  read -r wall peak < "$work/time"
  psf=$(grep -o 'PSF [0-9.]* s, read-back' "$work/log" | grep -o '[0-9.]*' | head -1)
  size=$(stat -c %s "$work/out/psf.h5")
  [ "$i" -eq 0 ] && { echo "warm-up: wall ${wall} s, PSF ${psf} s"; continue; }
  ratio=$(python3 -c "print(f'{$wall / $psf:.2f}')")
  echo "run $i: wall ${wall} s, PSF ${psf} s, wall / PSF ${ratio}, peak $((peak / 1024)) MiB, psf.h5 ${size} bytes"
  walls+=("$wall"); psfs+=("$psf"); ratios+=("$ratio")
  grep '^time:' "$work/log"
done
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print a[int((NR + 1) / 2)]}'; }
echo "median of $runs: wall $(median "${walls[@]}") s, PSF $(median "${psfs[@]}") s, wall / PSF $(median "${ratios[@]}")"
