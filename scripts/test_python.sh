#!/usr/bin/env bash
# The Python package's tests (python/tests, pytest), run by scripts/test.sh after the C++ suite,
# on the OpenCL CPU device. Two ways to get the package:
#   bash scripts/test_python.sh        the extension of the CMake build in ./build (configured with
#                                      QDO_PYTHON=ON, as scripts/build.sh does), staged in
#                                      build/pystage with python/qdo: the core is compiled once for
#                                      CTest and Python. Run with the interpreter CMake built it for.
#   bash scripts/test_python.sh --pip  `pip install .` into build/venv (Debian's numpy, torch and
#                                      pytest visible: --system-site-packages), as a user installs
#                                      it: pip fetches scikit-build-core from PyPI and builds its own
#                                      copy of the core in build/python. Also taken when ./build has
#                                      no Python extension.
# With QDO_REQUIRE_ALL=1 (CI) a skipped test fails.
set -euo pipefail
cd "$(dirname "$0")/.."
mode=build
case "${1:-}" in
  "") ;;
  --pip) mode=pip ;;
  *) echo "test_python.sh: unknown argument '$1' (allowed: none, or --pip)" >&2; exit 2 ;;
esac
if [ "$mode" = build ] && ! grep -q '^QDO_PYTHON:BOOL=ON$' build/CMakeCache.txt 2> /dev/null; then
  echo "test_python: build/ has no Python extension (QDO_PYTHON is not ON there): using pip install"
  mode=pip
fi
if [ "$mode" = build ]; then
  echo "test_python: the extension of build/ (target _qdo, staged in build/pystage)"
  cmake --build build -j"$(nproc)" --target qdo_python_stage > build/pystage.log 2>&1 || { tail -n 40 build/pystage.log; exit 1; }
  python=$(cat build/pystage/python-executable)
  export PYTHONPATH="$PWD/build/pystage${PYTHONPATH:+:$PYTHONPATH}"
else
  venv=build/venv
  if [ ! -x "$venv/bin/python" ]; then
    /usr/bin/python3 -m venv --system-site-packages "$venv"
  fi
  echo "test_python: pip install . (build dir build/python)"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check .
  python="$PWD/$venv/bin/python"
fi
export QDO_DEVICE="${QDO_DEVICE:-cpu}"
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$PWD/build/kernel-cache}"
export QDO_BINARY="${QDO_BINARY:-$PWD/build/qdo}"
log=build/pytest.log
set +e
# The package imported must be the one just built, not an installed one.
(cd python/tests && "$python" -c 'import qdo, sys; print("test_python: qdo from", qdo.__file__)' &&
   "$python" -m pytest -q -rs -p no:cacheprovider .) 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
set -e
if [ "$rc" -ne 0 ]; then exit "$rc"; fi
if [ "${QDO_REQUIRE_ALL:-0}" = "1" ] && grep -q "skipped" "$log"; then
  echo "test_python: QDO_REQUIRE_ALL=1 and some tests were skipped (see above)"
  exit 1
fi
