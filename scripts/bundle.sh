#!/usr/bin/env bash
# Packs this build for a machine that has an OpenCL driver but not qdo's build dependencies (the
# GPU tables of BENCHMARKS.md were measured this way: built here on Debian 12, run on an Ubuntu
# 24.04 machine with an NVIDIA driver). The archive holds the programs, every shared library they
# load except glibc's own, and the CAVE test crops and spectral tables the tests read.
# On the other machine, from a checkout of the same commit: `source scripts/bundle_env.sh BUNDLE`.
# Usage: scripts/bundle.sh [OUT.tar.xz=build/qdo-bundle.tar.xz]
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-build/qdo-bundle.tar.xz}"
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/build" "$stage/lib" "$stage/shared/data/hsi"
cp build/qdo build/qdo_tests build/bench_psf build/bench_step build/bench_fft "$stage/build/"
cp -r ../shared/data/hsi/cave ../shared/data/hsi/README.md "$stage/shared/data/hsi/"
cp -r ../shared/data/spectral "$stage/shared/data/"
for b in "$stage"/build/*; do ldd "$b"; done | awk '/=>/ {print $3}' | sort -u |
  grep -v -E '/(libc|libm|libdl|libpthread|librt)\.so|ld-linux' | xargs -I{} cp -L {} "$stage/lib/"
tar -C "$stage" -cJf "$out" build lib shared
echo "bundle: $out ($(du -h "$out" | cut -f1))"
