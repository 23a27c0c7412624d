#!/usr/bin/env bash
# Several `qdo psf` variants side by side (the whole-command target of psf_command.sh): one warm-up of each,
# then R rounds in which every variant runs once, in turn, so that a drift of the machine's speed
# (~20 % within a session on the CI-class VM) hits all of them alike. Per variant it prints the
# median wall time (min, max), the median PSF compute time the command prints, the median of the
# per-run ratios wall / PSF and the peak memory (/usr/bin/time).
#
# Usage: bench/psf_command_ab.sh RUNS PRESET VARIANT [VARIANT ...]
#   VARIANT: LABEL=WORDS, WORDS being optional VAR=VALUE settings and then the qdo binary, e.g.
#     bench/psf_command_ab.sh 7 paper old=/tmp/old/build/qdo new=build/qdo
#     bench/psf_command_ab.sh 6 paper b2='QDO_STREAM_BANDS=2 build/qdo' b8='QDO_STREAM_BANDS=8 build/qdo'
# Environment: as for qdo (QDO_DEVICE, QDO_CACHE_DIR, ...).
set -euo pipefail
(($# >= 3)) || { sed -n '2,12p' "$0" >&2; exit 2; }
runs="$1"; preset="$2"; shift 2
[[ "$runs" =~ ^[1-9][0-9]*$ ]] || { echo "psf_command_ab: RUNS must be an integer >= 1, not '$runs'" >&2; exit 2; }
labels=(); cmds=()
for v in "$@"; do
  [[ "$v" == *=* ]] || { echo "psf_command_ab: a variant is LABEL=WORDS, not '$v'" >&2; exit 2; }
  labels+=("${v%%=*}"); cmds+=("${v#*=}")
done
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
one() {  # one run of variant $1; appends "wall psf peak_kib" to $work/$1.txt
  local words
  read -ra words <<< "${cmds[$1]}"
  rm -rf "$work/out"
  /usr/bin/time -f "%e %M" -o "$work/time" env "${words[@]}" psf --preset "$preset" --design lens:550 --out "$work/out" \
    > "$work/log" 2>&1 || { echo "psf_command_ab: variant ${labels[$1]} failed:" >&2; cat "$work/log" >&2; exit 1; }
  local wall peak psf
  read -r wall peak < "$work/time"
  psf=$(grep -o 'PSF [0-9.]* s, read-back' "$work/log" | grep -o '[0-9.]*' | head -1)
  [ -n "$2" ] && echo "$wall $psf $peak" >> "$work/$1.txt"
  return 0
}
for i in "${!labels[@]}"; do one "$i" ""; done  # warm-up
for r in $(seq 1 "$runs"); do
  for i in "${!labels[@]}"; do one "$i" keep; done
  echo "round $r of $runs done" >&2
done
echo "| variant | runs | median wall s (min, max) | median PSF s | median wall / PSF | peak MiB |"
echo "|---|---:|---:|---:|---:|---:|"
for i in "${!labels[@]}"; do
  python3 - "${labels[$i]}" "$work/$i.txt" <<'EOF'
import statistics, sys
label, path = sys.argv[1], sys.argv[2]
rows = [tuple(map(float, line.split())) for line in open(path) if line.strip()]
wall = [r[0] for r in rows]; psf = [r[1] for r in rows]; peak = [r[2] for r in rows]
ratio = statistics.median(r[0] / r[1] for r in rows)
print(f"| {label} | {len(rows)} | {statistics.median(wall):.2f} ({min(wall):.2f}, {max(wall):.2f}) | "
      f"{statistics.median(psf):.3f} | {ratio:.2f} | {max(peak) / 1024:.0f} |")
EOF
done
