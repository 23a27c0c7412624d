#!/usr/bin/env bash
# qdo's joint-training step against a plain-PyTorch reference (bench/joint_torch.py), stage by stage, in
# one run: build/bench_train --presets PRESET (qdo: OpenCL optics and camera, LibTorch network) and
# bench/joint_torch.py --preset PRESET (torch.fft optics and camera, torch.nn network, one autograd graph)
# with the same batch, the same repeats and all cores as torch threads (bench_train sets LibTorch to
# hardware_concurrency; PoCL uses every core). Writes OUT/joint_torch.md: one row per stage with qdo's
# median, the reference's median and qdo / reference (< 1: qdo faster), plus the machine and the date.
# With CHECK=1 (the default) it first runs the reference's float64 checks, including a comparison with
# qdo's own f64 sensor PSF of the 550 nm lens (`qdo psf`, read with $PY's h5py: Debian's python3-h5py).
#
# Usage: bench/joint_torch.sh OUT [REPEATS=5] [BATCH=4]
#        env: BUILD=build (where bench_train and qdo are), PY=/usr/bin/python3 (a python with torch),
#             THREADS=$(nproc), CHECK=1, PRESET=small (or paper: N 1024, scenes of 512 x 512 and the
#             paper's Res-UNet, depth 7 and root 32, on both sides; its check stays at small)
# Timings on a shared machine are noisy: the load average at the start and the end goes into the report.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: bench/joint_torch.sh OUT [REPEATS] [BATCH]}
REPEATS=${2:-5}
BATCH=${3:-4}
BUILD=${BUILD:-build}
PY=${PY:-/usr/bin/python3}
THREADS=${THREADS:-$(nproc)}
CHECK=${CHECK:-1}
PRESET=${PRESET:-small}
case "$PRESET" in
  small) DECODER=resunet; NET=(--depth 4 --root 16) ;;
  paper) DECODER=resunet:paper; NET=(--depth 7 --root 32) ;;
  *) echo "joint_torch.sh: PRESET=$PRESET: small or paper" >&2; exit 2 ;;
esac
mkdir -p "$OUT"
load0=$(cut -d' ' -f1-3 /proc/loadavg)
date -u +"%Y-%m-%d %H:%M:%S UTC" > "$OUT/date.txt"

if [ "$CHECK" = 1 ]; then
  qpsf=""
  if "$BUILD/qdo" psf --preset small --design lens:550 --precision f64 --out "$OUT/qdo_psf" --into-existing \
       > "$OUT/qdo_psf.log" 2>&1 &&
     "$PY" -c \
       "import h5py, numpy as np, sys; np.save(sys.argv[2], h5py.File(sys.argv[1])['psf_sensor'][()])" \
       "$OUT/qdo_psf/psf.h5" "$OUT/qdo_psf/psf_sensor.npy" 2>> "$OUT/qdo_psf.log"; then
    qpsf="--qdo-psf $OUT/qdo_psf/psf_sensor.npy"
  else
    echo "joint_torch: no qdo PSF to compare (see $OUT/qdo_psf.log)" >&2
  fi
  t0=$(date +%s.%N)
  # shellcheck disable=SC2086
  "$PY" bench/joint_torch.py --check --threads "$THREADS" $qpsf > "$OUT/check.txt" 2>&1 ||
    { cat "$OUT/check.txt"; exit 1; }
  echo "check took $(echo "$(date +%s.%N) - $t0" | bc) s" >> "$OUT/check.txt"
  cat "$OUT/check.txt"
fi

t0=$(date +%s.%N)
"$BUILD/bench_train" --presets "$PRESET" --decoder "$DECODER" --repeats "$REPEATS" --batch "$BATCH" --out "$OUT/bench_train.md" \
  > "$OUT/bench_train.log" 2>&1 || { tail -20 "$OUT/bench_train.log"; exit 1; }
t1=$(date +%s.%N)
"$PY" bench/joint_torch.py --preset "$PRESET" "${NET[@]}" --repeats "$REPEATS" --batch "$BATCH" --threads "$THREADS" \
  --json "$OUT/joint_torch.json" > "$OUT/joint_torch.log" 2>&1 || { tail -20 "$OUT/joint_torch.log"; exit 1; }
t2=$(date +%s.%N)
load1=$(cut -d' ' -f1-3 /proc/loadavg)

"$PY" - "$OUT" "$(echo "$t1 - $t0" | bc)" "$(echo "$t2 - $t1" | bc)" "$load0" "$load1" "$REPEATS" "$CHECK" "$PRESET" "$DECODER" "${NET[*]}" <<'PY'
import json, subprocess, sys
out, qdo_wall, torch_wall, load0, load1, repeats, check, preset, decoder, net = sys.argv[1:11]
qdo = {}
for line in open(f"{out}/bench_train.md"):
    f = [x.strip() for x in line.strip().strip("|").split("|")]
    if len(f) == 6 and f[0] == preset:
        try:
            qdo[f[3]] = float(f[4])
        except ValueError:
            pass
device = next((l.strip() for l in open(f"{out}/bench_train.md") if l.startswith("Device:")), "")
qdo_sizes = next((l.strip().rstrip(":") for l in open(f"{out}/bench_train.log") if l.startswith(preset + " (")), "")
ref = json.load(open(f"{out}/joint_torch.json"))
t, sz = ref["times"], ref["sizes"]
lscpu = subprocess.run(["lscpu"], capture_output=True, text=True).stdout
def field(name):
    return next((l.split(":", 1)[1].strip() for l in lscpu.splitlines() if l.startswith(name + ":")), "?")
rows = [  # (stage, qdo row, torch row, remark)
    ("optics forward", "optics forward (PSF)", "optics forward",
     "reference includes the QDO+A quantizer and ring expansion (N^2 gather); qdo takes a ready N x N map"),
    ("camera forward", "camera (batch of scenes -> RGB)", "camera forward",
     "**not fully comparable**: qdo reuses the PSF's cached OTF (same PSF every repeat); the reference "
     "transforms the PSF each call"),
    ("network forward + backward", "network forward + backward (MAE)", "network forward + backward",
     "both LibTorch CPU; qdo adds double <-> float host copies"),
    ("camera backward (dL/dRGB -> dL/dPSF)", "camera adjoint (dL/dRGB -> dL/dPSF)", "camera backward", ""),
    ("optics backward (dL/dPSF -> dL/dH)", "PSF-chain adjoint (dL/dPSF -> dL/dH)", "optics backward",
     "reference includes the quantizer and expansion backward (to N/2 rings and L offsets)"),
    ("network Adam step", "network Adam step", "network Adam step", ""),
    ("whole step", "whole step", "whole step",
     "qdo: the stages above in sequence; reference: one graph, MAE + beta L_aq, one backward, "
     "network and optics Adam"),
]
L = []
L.append(f"# qdo vs a plain-PyTorch reference: one joint-training step, stage by stage (preset {preset})\n")
L.append(f"- date: {open(out + '/date.txt').read().strip()}")
L.append(f"- machine: {field('Model name')}, {field('CPU(s)')} CPUs ({field('Core(s) per socket')} cores per socket, "
         f"{field('Socket(s)')} socket(s), {field('Thread(s) per core')} thread(s) per core)")
L.append(f"- load average (1, 5, 15 min) at the start: {load0}; at the end: {load1} (the machine is shared: "
         "other jobs ran meanwhile, so the numbers are noisy)")
L.append(f"- qdo: `build/bench_train --presets {preset} --decoder {decoder} --repeats {repeats} --batch {ref['batch']}` ({device}; "
         f"median of {repeats} after one warm-up; run took {float(qdo_wall):.0f} s, including its extra rows)")
L.append(f"- reference: `bench/joint_torch.py --preset {preset} {net} --repeats {repeats} --batch {ref['batch']} "
         f"--threads {ref['threads']}` (torch {ref['torch']}, {ref['device']}, {ref['threads']} threads, "
         f"float32/complex64, QDO+A L=4, median of {repeats} after one warm-up; run took {float(torch_wall):.0f} s)")
L.append("- sizes (both): " + ", ".join(f"{k} {v}" for k, v in sz.items()) +
         f"; Res-UNet depth {ref['depth']}, root {ref['root']}, batch {ref['batch']} (bench_train: {qdo_sizes})\n")
L.append("| stage | qdo (s) | reference (s) | qdo / reference | remark |")
L.append("|---|---:|---:|---:|---|")
sq = sr = 0.0
for name, qk, rk, rem in rows:
    q, r = qdo.get(qk), t.get(rk)
    if name != "whole step" and q is not None:
        sq += q
        sr += r
    ratio = f"{q / r:.2f}" if q and r else "n/a"
    L.append(f"| {name} | {q if q is not None else float('nan'):.4f} | {r:.4f} | {ratio} | {rem} |")
L.append(f"| sum of the stages | {sq:.4f} | {sr:.4f} | {sq / sr:.2f} | |")
d = qdo.get("qdo design's step (Designer + JointTrainer, radial path)")
if d is not None:
    L.append(f"| qdo design's step (radial path) vs the reference's whole step | {d:.4f} | {t['whole step']:.4f} | "
             f"({d / t['whole step']:.2f}) | **not comparable**: qdo's radial PSF engine (no 2-D FFT) and the "
             "circular patch camera, random crops; shown for information |")
L.append(f"| optics Adam step (reference only) | | {t['optics Adam step']:.4f} | | no such row in bench_train |")
L.append("")
L.append("Ratios below 1: qdo is faster. The physics is the same (the reference's f64 sensor PSF of the "
         "550 nm lens matches `qdo psf`'s when CHECK=1, see check.txt); the work per stage is the same "
         "except where the remarks say. Raw outputs: bench_train.md, bench_train.log, joint_torch.log, "
         "joint_torch.json" + (", check.txt" if check == "1" else "") + ".")
open(f"{out}/joint_torch.md", "w").write("\n".join(L) + "\n")
print("\n".join(L))
PY
