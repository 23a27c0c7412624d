#!/usr/bin/env bash
# Builds qdo from source on a machine that has a compiler, CMake and most of qdo's dependencies but
# not clFFT, matio or VkFFT, and a LibTorch of its own: the lent GPU machines (Ubuntu 24.04, CUDA 13,
# PyTorch 2.11+cu130 in /opt/torch/.venv). This is how the network decoder was checked with a
# CUDA LibTorch (docs/commands.md, "The network decoder"; BENCHMARKS.md, "GPU"); scripts/bundle.sh
# instead carries binaries built here, which cannot use another machine's LibTorch.
#
#   here:  scripts/device_build.sh pack [N_TRAIN=10]
#            writes build-devprefix/: clFFT, matio and VkFFT (headers, libraries, a relocatable
#            clFFT CMake config), the 3 CAVE test crops, the spectral tables and the first N_TRAIN
#            training scenes (about 45 MB: a device call carries 64 MiB at most).
#   there: scripts/device_build.sh build [TORCH_DIR]
#            configures build/ with that prefix and Torch_DIR (default: the pip PyTorch's
#            share/cmake/Torch), builds qdo and qdo_tests, registers NVIDIA's OpenCL driver with the
#            ICD loader when it finds one, and links ../shared to the carried data. Then e.g.
#              export LD_LIBRARY_PATH=$PWD/build-devprefix/lib
#              export LD_PRELOAD=$(g++ -print-file-name=libstdc++.so.6)   # see below
#              QDO_TORCH_DEVICE=cuda build/qdo_tests --test-suite=net,joint
# PyTorch's pip wheels export a statically linked copy of libstdc++'s std::filesystem
# (pytorch/pytorch#133437) that wins symbol resolution over the compiler's own; with torch
# 2.11+cu130 std::filesystem::remove_all (used by the tests' clean-up) then jumped to address 0.
# Preloading the compiler's libstdc++ puts its definitions first.
set -euo pipefail
cd "$(dirname "$0")/.."
pre="$PWD/build-devprefix"
case "${1:-}" in
pack)
  n_train="${2:-10}"
  # Replaces only a folder this script made (its marker file), never anything else at that path.
  if [ -e "$pre" ] && [ ! -e "$pre/.qdo-device-prefix" ]; then
    echo "device_build: $pre exists and was not made by this script: left as it is" >&2; exit 2
  fi
  rm -rf "$pre" && mkdir -p "$pre/include" "$pre/lib" "$pre/lib/cmake/clFFT" "$pre/lib/pkgconfig" \
    "$pre/shared/data/hsi/cave_train"
  cp /usr/include/clFFT.h /usr/include/clFFT.version.h /usr/include/matio.h /usr/include/matio_pubconf.h \
    /usr/include/vkFFT.h "$pre/include/"
  cp -L /usr/lib/x86_64-linux-gnu/libclFFT.so.2 /usr/lib/x86_64-linux-gnu/libmatio.so.11 "$pre/lib/"
  ln -s libclFFT.so.2 "$pre/lib/libclFFT.so"
  ln -s libmatio.so.11 "$pre/lib/libmatio.so"
  cat > "$pre/lib/cmake/clFFT/clFFTConfig.cmake" <<'EOF'
# clFFT 2.12 (Debian libclfft-dev), relocated: the imported target clFFT as Debian's config defines it.
get_filename_component(_p "${CMAKE_CURRENT_LIST_DIR}/../../.." ABSOLUTE)
if(NOT TARGET clFFT)
  add_library(clFFT SHARED IMPORTED)
  set_target_properties(clFFT PROPERTIES IMPORTED_LOCATION "${_p}/lib/libclFFT.so.2"
                        INTERFACE_INCLUDE_DIRECTORIES "${_p}/include")
endif()
set(clFFT_FOUND TRUE)
EOF
  cat > "$pre/lib/pkgconfig/matio.pc" <<'EOF'
prefix=${pcfiledir}/../..
libdir=${prefix}/lib
includedir=${prefix}/include
Name: MATIO
Description: MATIO Library (Debian libmatio-dev 1.5.23, relocated)
Version: 1.5.23
Libs: -L${libdir} -lmatio
Cflags: -I${includedir}
EOF
  cp -r ../shared/data/hsi/cave ../shared/data/hsi/README.md "$pre/shared/data/hsi/"
  cp -r ../shared/data/spectral "$pre/shared/data/"
  if [ "$n_train" -gt 0 ]; then  # (head -n 0 would end the pipe early: a failure under pipefail)
    find ../shared/data/hsi/cave_train -name '*.mat' | sort | head -n "$n_train" |
      xargs -I{} cp {} "$pre/shared/data/hsi/cave_train/"
  fi
  touch "$pre/.qdo-device-prefix"
  echo "device_build: $pre ($(du -sh "$pre" | cut -f1))"
  ;;
build)
  [ -d "$pre" ] || { echo "device_build: $pre missing: run 'scripts/device_build.sh pack' on the build machine and carry it" >&2; exit 2; }
  torch_dir="${2:-$(python3 -c 'import torch, os; print(os.path.join(os.path.dirname(torch.__file__), "share/cmake/Torch"))' 2>/dev/null || true)}"
  export LD_LIBRARY_PATH="$pre/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
  export PKG_CONFIG_PATH="$pre/lib/pkgconfig${PKG_CONFIG_PATH:+:$PKG_CONFIG_PATH}"
  if [ ! -e /etc/OpenCL/vendors/nvidia.icd ]; then
    lib="$(find / -xdev -name 'libnvidia-opencl.so.1' 2>/dev/null | head -1)"
    if [ -n "$lib" ]; then mkdir -p /etc/OpenCL/vendors && echo "$lib" > /etc/OpenCL/vendors/nvidia.icd; fi
  fi
  [ -e ../shared ] || ln -s "$pre/shared" ../shared
  bdir="${QDO_DEVICE_BUILD:-build}"  # env: QDO_DEVICE_BUILD (folder), QDO_DEVICE_CMAKE_ARGS (more cmake options), QDO_DEVICE_TARGETS (default: qdo qdo_tests)
  mkdir -p "$bdir"
  # shellcheck disable=SC2086
  cmake -S . -B "$bdir" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$pre" -DclFFT_DIR="$pre/lib/cmake/clFFT" \
    -DVKFFT_INCLUDE_DIR="$pre/include" -DTorch_DIR="$torch_dir" -DCMAKE_BUILD_RPATH="$pre/lib" ${QDO_DEVICE_CMAKE_ARGS:-} > "$bdir/device-configure.log" 2>&1 ||
    { tail -40 "$bdir/device-configure.log"; exit 1; }
  # shellcheck disable=SC2086
  cmake --build "$bdir" --target ${QDO_DEVICE_TARGETS:-qdo qdo_tests} -j "$(nproc)" > "$bdir/device-build.log" 2>&1 || { grep -B2 -A20 -m3 "error" "$bdir/device-build.log" | head -80; exit 1; }
  echo "device_build: built in $bdir with LibTorch from $torch_dir; run with LD_LIBRARY_PATH=$pre/lib and, for a pip LibTorch, LD_PRELOAD=$(g++ -print-file-name=libstdc++.so.6)"
  ;;
*)
  echo "usage: scripts/device_build.sh pack [N_TRAIN] | build [TORCH_DIR]" >&2; exit 2 ;;
esac
