#!/usr/bin/env bash
# Data-parallel joint training: the time of one `qdo design --decoder resunet`
# step in one process and under `mpirun -np N` (each rank batch / N scenes, one allreduce per
# step, batch norm synchronised), median step_s of log.csv after WARMUP steps. Prints one markdown
# row per configuration: ranks, LibTorch threads per rank, median s/step, speed-up over the first.
# Usage: bench/bench_dp.sh [QDO_BINARY] [STEPS] [CONFIG...]   (defaults: build/qdo 12 1 2)
# CONFIG: N (ranks; LibTorch threads per rank cores / N, at least 1) or N:T (T threads per rank).
# Environment: PRESET (small), DECODER (resunet:depth=3,root=8), BATCH (4), WARMUP (2),
# QDO_DEVICE (cpu), VERBOSE (set: print every step's step_s to stderr).
set -euo pipefail
qdo="$(realpath "${1:-build/qdo}")"; steps="${2:-12}"; shift $(( $# < 2 ? $# : 2 ))
ranks_list=("$@"); [ ${#ranks_list[@]} -eq 0 ] && ranks_list=(1 2)
preset="${PRESET:-small}"; decoder="${DECODER:-resunet:depth=3,root=8}"; batch="${BATCH:-4}"; warmup="${WARMUP:-2}"
cores="$(nproc)"; export QDO_DEVICE="${QDO_DEVICE:-cpu}"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print a[int((NR + 1) / 2)]}'; }
base=""
echo "| ranks | LibTorch threads per rank | median s/step | speed-up |"
echo "|---|---|---|---|"
for c in "${ranks_list[@]}"; do
  n=${c%%:*}; i=$(( ${i:-0} + 1 ))
  threads=$(( cores / n > 0 ? cores / n : 1 )); [[ "$c" == *:* ]] && threads=${c##*:}
  launcher=(); [ "$n" -gt 1 ] && launcher=(mpirun --oversubscribe -np "$n")
  QDO_TORCH_THREADS=$threads "${launcher[@]}" "$qdo" design --recipe qdo --preset "$preset" --decoder "$decoder" --batch "$batch" \
    --epochs 1 --steps-per-epoch "$steps" --checkpoint-every "$steps" --seed 1 --out "$work/r$i" > "$work/log$i" 2>&1 \
    || { cat "$work/log$i"; exit 1; }
  [ -n "${VERBOSE:-}" ] && cut -d, -f1,6 "$work/r$i/log.csv" | tr "\n" " " >&2 && echo >&2
  mapfile -t times < <(awk -F, -v w="$warmup" 'NR > 1 + w {print $6}' "$work/r$i/log.csv")
  m=$(median "${times[@]}")
  [ -z "$base" ] && base=$m
  echo "| $n | $threads | $(printf '%.3f' "$m") | $(python3 -c "print(f'{$base / $m:.2f}x')") |"
done
