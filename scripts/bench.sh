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
# The framework baseline: NumPy's PSF stack; Debian's python3-numpy, installed if missing.
if ! /usr/bin/python3 -c "import numpy" 2> /dev/null; then
  sudo_cmd=""; [[ $(id -u) -ne 0 ]] && sudo_cmd="sudo"
  $sudo_cmd env DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-numpy > /dev/null
fi
/usr/bin/python3 bench/psf_numpy.py --repeats 3 | tee "$out/psf_numpy.txt"
# The same in PyTorch (Debian's python3-torch, CPU; bench/psf_torch.py --device cuda on a GPU).
if /usr/bin/python3 -c "import torch" 2> /dev/null; then
  /usr/bin/python3 bench/psf_torch.py --device cpu --repeats 3 | tee "$out/psf_torch.txt"
fi
# The whole paper-preset PSF command against its in-process compute, and with --compress.
bash bench/psf_command.sh ./build/qdo paper 7 | tee "$out/psf_command.txt"
bash bench/psf_command.sh ./build/qdo paper 5 --compress | tee "$out/psf_command_compress.txt"
# What crossing between PyTorch and qdo costs (needs the package: scripts/build.sh stages it in
# build/pystage for Debian's python3; a pip install into build/venv serves too).
if [ -f build/pystage/python-executable ]; then
  PYTHONPATH="$PWD/build/pystage" "$(cat build/pystage/python-executable)" bench/python_overhead.py | tee "$out/python.txt"
elif [ -x build/venv/bin/python ]; then build/venv/bin/python bench/python_overhead.py | tee "$out/python.txt"; fi
# One joint-training step (optics + Res-UNet), when the build has LibTorch (QDO_TORCH).
if [ -x build/bench_train ]; then ./build/bench_train --presets small,paper --repeats 3 --out "$out/train.md"; fi
echo "bench: tables in $out/"
