# Sourced from the root of a checkout on the target machine: `source scripts/bundle_env.sh BUNDLE`.
# Unpacks a scripts/bundle.sh archive to /tmp/qdo-bundle, points the loader at its libraries,
# registers the NVIDIA OpenCL driver with the ICD loader when it finds one (needs root), and lays
# out the paths the test binary was compiled with (the checkout's build/ and ../shared, as the
# absolute paths of the machine that built it: /work/main and /work/shared there). Then e.g.
#   QDO_DEVICE=gpu build/qdo_tests --test-case-exclude='*[slow]*,*[measure]*'
#   QDO_DEVICE=gpu build/bench_psf --sizes 1024 --precision f32,f64
bundle="${1:?usage: source scripts/bundle_env.sh BUNDLE.tar.xz}"
b=/tmp/qdo-bundle
[ -d "$b/build" ] || { mkdir -p "$b" && tar -C "$b" -xJf "$bundle"; }
export LD_LIBRARY_PATH="$b/lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
if [ ! -e /etc/OpenCL/vendors/nvidia.icd ]; then
  lib="$(find / -xdev -name 'libnvidia-opencl.so.1' 2>/dev/null | head -1)"
  [ -n "$lib" ] && mkdir -p /etc/OpenCL/vendors && echo "$lib" > /etc/OpenCL/vendors/nvidia.icd
fi
if [ -e build ] && [ ! -L build ]; then
  echo "bundle_env: ./build exists and is not a link to a bundle: left as it is" >&2
  return 1
fi
ln -sfn "$b/build" build
bdir="$(cat "$b/build/BUILD_DIR" 2>/dev/null || echo build)"
[ "$bdir" = build ] || [ -e "$bdir" ] || ln -sfn "$b/build" "$bdir"
mkdir -p /work
[ "$PWD" = /work/main ] || ln -sfn "$PWD" /work/main
[ -e /work/shared ] || ln -sfn "$b/shared" /work/shared
echo "bundle_env: $(build/qdo devices 2>&1 | tail -1)"
