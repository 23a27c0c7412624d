#!/usr/bin/env bash
# Runs every benchmark of BENCHMARKS.md in sequence (about 25 minutes on 2 cores) and writes their
# markdown tables to ${1:-out/bench}/. Run it on an otherwise idle machine; nothing is asserted.
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out/bench}"
mkdir -p "$out"
bash scripts/build.sh
export QDO_DEVICE="${QDO_DEVICE:-cpu}"
./build/bench_pareto --n 1024 --repeats 3 --out "$out/pareto.md"
./build/bench_step --presets small,paper --repeats 3 --cpu-repeats 1 --out "$out/step.md"
./build/bench_fft --repeats 3 --out "$out/fft.md"
./build/bench_psf --sizes 256,512,1024 --repeats 3 --out "$out/psf.md"
./build/bench_skip --data ../shared/data/hsi/cave --repeats 3 --out "$out/skip.md"
./build/bench_commands --qdo ./build/qdo --repeats 11 --out "$out/commands.md"
echo "bench: tables in $out/"
