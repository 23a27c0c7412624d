#!/usr/bin/env bash
# Installs the Debian packages qdo needs to build, test and run. Idempotent: packages
# already present are skipped, so a prepared machine pays nothing.
#   bash scripts/install-deps.sh [all]   everything: the tool, its tests, the network decoder
#                                        (LibTorch), MPI and the Python package
#   bash scripts/install-deps.sh core    what the tool itself needs to build and run (scripts/demo.sh)
#   bash scripts/install-deps.sh --list [all|core]   print the set's package names, one a line, and exit
set -euo pipefail
list_only=0
if [ "${1:-}" = --list ]; then list_only=1; shift; fi
set_name=${1:-all}
case "$set_name" in
  all|core) ;;
  *) echo "install-deps.sh: unknown set '$set_name' (allowed: all, core)" >&2; exit 2 ;;
esac
core=(
  build-essential cmake pkg-config
  ocl-icd-opencl-dev opencl-c-headers opencl-clhpp-headers pocl-opencl-icd clinfo
  libclfft-dev           # FFT on the OpenCL device
  libvkfft-dev           # second FFT backend on the OpenCL device (header-only VkFFT)
  libfftw3-dev           # CPU reference FFT (double)
  libeigen3-dev          # host linear algebra
  libhdf5-dev            # result files and HDF5 / .mat v7.3 cubes
  libmatio-dev           # MATLAB .mat v5 / v7.3 reader
  nlohmann-json3-dev     # configuration files
  libpng-dev             # figures, 16-bit PNG captures
  libtiff-dev            # 16-bit TIFF captures (qdo calibrate, qdo reconstruct)
  libraw-dev             # camera raw captures: DNG and vendor raws (qdo calibrate, qdo reconstruct)
  libplplot-dev plplot-driver-cairo  # figures: PNG through cairo and SVG, with axes, legends, colour bars
  libcli11-dev           # the command line (header-only CLI11)
  doctest-dev            # tests (header-only; the configure step looks for it)
)
extra=(
  klayout                # tests: an independent GDSII reader for the mask round trip
  pybind11-dev           # the Python extension qdo._qdo (pyproject.toml)
  python3-venv python3-pip python3-numpy python3-pytest  # the Python package's build and tests
  python3-torch          # qdo.torch (the PyTorch operators) and its tests
  python3-h5py           # the Python tests read arrays with h5py (its dtypes must be accepted)
  libopenmpi-dev openmpi-bin  # qdo sweep / qdo design under mpirun; the build without MPI works too
  libtorch-dev           # the Res-UNet decoder in C++ (LibTorch 1.13, find_package(Torch); target qdo_net)
)
pkgs=("${core[@]}")
[ "$set_name" = all ] && pkgs+=("${extra[@]}")
if [ "$list_only" = 1 ]; then printf '%s\n' "${pkgs[@]}"; exit 0; fi
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "install-deps: installing ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
  echo "install-deps: all packages present ($set_name)"
fi
