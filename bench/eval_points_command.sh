#!/usr/bin/env bash
# The whole `qdo eval-points` command against `qdo eval` on the same run (the baseline: one
# distance, one decoder) in the same session: runs each variant R times after one warm-up (the
# variants in turn, round by round), each under /usr/bin/time, and prints the median wall time with
# min and max and the peak memory. Variants: eval (qdo eval RUN), one point (eval-points --distances 1
# --angles 0: one distance, two decoders, the on-axis asm reference), and the default grid
# (10 distances x 2 decoders, 9 field angles).
# Usage: bench/eval_points_command.sh RUN [QDO_BINARY] [RUNS] [extra options for both commands, e.g. --data DIR]
set -euo pipefail
run="$1"; qdo="${2:-build/qdo}"; runs="${3:-5}"; shift $(( $# < 3 ? $# : 3 ))
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
declare -A walls peaks
variants=(eval one_point default_grid)
cmd() {
  case "$1" in
    eval) echo "$qdo eval $run --renders 0 --out $work/out" ;;
    one_point) echo "$qdo eval-points $run --distances 1 --angles 0 --out $work/out" ;;
    default_grid) echo "$qdo eval-points $run --out $work/out" ;;
  esac
}
for i in $(seq 0 "$runs"); do
  for v in "${variants[@]}"; do
    rm -rf "$work/out"
    # shellcheck disable=SC2046
    /usr/bin/time -f "%e %M" -o "$work/time" $(cmd "$v") "$@" > "$work/log" 2>&1 || { cat "$work/log"; exit 1; }
    read -r wall peak < "$work/time"
    [ "$i" -eq 0 ] && { echo "warm-up $v: wall ${wall} s"; continue; }
    echo "run $i $v: wall ${wall} s, peak $((peak / 1024)) MiB"
    walls[$v]+="$wall "; peaks[$v]+="$peak "
  done
done
stats() { printf '%s\n' $1 | sort -g | awk '{a[NR]=$1} END {printf "median %s s [min %s, max %s]", a[int((NR + 1) / 2)], a[1], a[NR]}'; }
for v in "${variants[@]}"; do
  echo "$v: $(stats "${walls[$v]}") over $runs runs, peak $(( $(printf '%s\n' ${peaks[$v]} | sort -g | tail -1) / 1024 )) MiB"
done
