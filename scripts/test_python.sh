#!/usr/bin/env bash
# The Python package's tests (python/tests, pytest), run by scripts/test.sh after the C++ suite:
# builds and installs the package with pip into build/venv, a virtual environment that sees
# Debian's numpy, torch and pytest (--system-site-packages), then runs pytest on the OpenCL CPU
# device. pip fetches scikit-build-core from PyPI (the build backend); the build itself uses the
# Debian packages of scripts/install-deps.sh. With QDO_REQUIRE_ALL=1 (CI) a skipped test fails.
set -euo pipefail
cd "$(dirname "$0")/.."
venv=build/venv
if [ ! -x "$venv/bin/python" ]; then
  /usr/bin/python3 -m venv --system-site-packages "$venv"
fi
echo "test_python: pip install . (build dir build/python)"
"$venv/bin/python" -m pip install --quiet --disable-pip-version-check .
export QDO_DEVICE="${QDO_DEVICE:-cpu}"
export QDO_CACHE_DIR="${QDO_CACHE_DIR:-$PWD/build/kernel-cache}"
export QDO_BINARY="${QDO_BINARY:-$PWD/build/qdo}"
log=build/pytest.log
set +e
(cd python/tests && "../../$venv/bin/python" -m pytest -q -rs -p no:cacheprovider .) 2>&1 | tee "$log"
rc=${PIPESTATUS[0]}
set -e
if [ "$rc" -ne 0 ]; then exit "$rc"; fi
if [ "${QDO_REQUIRE_ALL:-0}" = "1" ] && grep -q "skipped" "$log"; then
  echo "test_python: QDO_REQUIRE_ALL=1 and some tests were skipped (see above)"
  exit 1
fi
