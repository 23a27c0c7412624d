#!/usr/bin/env bash
# Packs this build for a machine that has an OpenCL driver but not qdo's build dependencies (the
# GPU tables of BENCHMARKS.md were measured this way: built here on Debian 12, run on an Ubuntu
# 24.04 machine with an NVIDIA driver). The archive holds the programs, every shared library they
# load except glibc's own, and the CAVE test crops and spectral tables the tests read.
# On the other machine, from a checkout of the same commit: `source scripts/bundle_env.sh BUNDLE`.
# Usage: scripts/bundle.sh [OUT.tar.xz=build/qdo-bundle.tar.xz] [BUILD_DIR=build]
# A build with LibTorch (QDO_TORCH, the default) links libtorch into qdo_tests, which makes the
# archive several hundred MB; for a small one configure a second build without it:
#   cmake -S . -B build-notorch -DQDO_TORCH=OFF -DCMAKE_BUILD_TYPE=Release && cmake --build build-notorch
#   scripts/bundle.sh build/qdo-bundle.tar.xz build-notorch
# (the test binary then expects the `qdo` binary at that build folder's path: bundle_env.sh links
# both build/ and the named folder to the bundle).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-build/qdo-bundle.tar.xz}"
bdir="${2:-build}"
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/build" "$stage/lib" "$stage/shared/data/hsi"
for f in qdo qdo_tests bench_psf bench_step bench_fft; do if [ -x "$bdir/$f" ]; then cp "$bdir/$f" "$stage/build/"; fi; done
cp -r ../shared/data/hsi/cave ../shared/data/hsi/README.md "$stage/shared/data/hsi/"
cp -r ../shared/data/spectral "$stage/shared/data/"
for b in "$stage"/build/*; do ldd "$b"; done | awk '/=>/ {print $3}' | sort -u |
  grep -v -E '/(libc|libm|libdl|libpthread|librt)\.so|ld-linux' | xargs -I{} cp -L {} "$stage/lib/"
echo "$bdir" > "$stage/build/BUILD_DIR"  # the folder the test binary was built in (bundle_env.sh)
tar -C "$stage" -cJf "$out" build lib shared
echo "bundle: $out ($(du -h "$out" | cut -f1))"
