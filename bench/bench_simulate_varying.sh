#!/bin/bash
# Timings of qdo simulate --depth / --field-grid on the small preset (CPU device), against plain qdo simulate.
# Usage: bench/bench_simulate_varying.sh   (BUILD_DIR: the build folder, default build)
# qdo simulate's own timing ("in X s": PSF + image + sensor), median of 5 runs after 1 warm-up;
# for the varying runs also the PSF part (varying.json psf_seconds).
cd "$(dirname "$0")/../${BUILD_DIR:-build}"
export QDO_DEVICE=cpu QDO_CACHE_DIR=$PWD/kernel-cache
# A work folder of its own, removed on exit: nothing else is deleted.
work=$(mktemp -d "${TMPDIR:-/tmp}/qdo_bench_simvar.XXXXXX")
trap 'rm -rf "$work"' EXIT
run() {
  name=$1; shift
  tot=(); psf=()
  for i in 0 1 2 3 4 5; do
    rm -rf "$work/$name"
    t=$(./qdo simulate "$@" --out "$work/$name" 2>/dev/null | grep -o "in [0-9.]* s (PSF" | head -1 | awk '{print $2}')
    p=$(python3 -c "import json;print(json.load(open('$work/$name/varying.json'))['psf_seconds'])" 2>/dev/null || echo 0)
    [ $i -gt 0 ] && tot+=($t) && psf+=($p)
  done
  python3 - "$name" "${tot[*]}" "${psf[*]}" <<'PY'
import sys, statistics as s
name, tot, psf = sys.argv[1], [float(x) for x in sys.argv[2].split()], [float(x) for x in sys.argv[3].split()]
def f(v):
    m = s.median(v); return f"{m:.3f} s +- {s.median([abs(x-m) for x in v]):.3f}"
if not any(psf):
    print(f"{name}: total {f(tot)}  (median +- median absolute deviation, 5 runs)")
else:
    print(f"{name}: total {f(tot)}; PSFs {f(psf)}; image = total - PSFs ~ {s.median(tot)-s.median(psf):.3f} s  (5 runs)")
PY
}
run plain --preset small --design lens:550
run depth_builtin_5layers --preset small --design lens:550 --depth builtin
run depth_builtin_output --preset small --design lens:550 --depth builtin --psf-placement output
run depth_builtin_1used --preset small --design lens:550 --depth builtin --depth-layers 0.05
run field_3x3 --preset small --design lens:550 --field-grid 3
run field_5x5 --preset small --design lens:550 --field-grid 5
run field_5x5_rank3 --preset small --design lens:550 --field-grid 5 --field-rank 3
run field_3x3_asm_edge2.3 --preset small --design lens:550 --field-grid 3 --field-edge-deg 2.3
