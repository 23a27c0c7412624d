#!/usr/bin/env bash
# The layers of src/ point down only (CTest entry "layers"). From the bottom:
#   runtime, data          OpenCL, FFT, kernel cache; configurations, scenes, files, materials
#   physics                the optical stages and their CPU references
#   decode                 decoders and their registry, the test-set evaluation, tiled decoding
#   design                 the optimiser, run folders
#   evaluate               eval of a run, eval-points, sweeps
#   asbuilt                the built camera: simulated captures, calibration outputs, fit, reconstruct
#   fab                    fabrication export and tolerance
#   cli                    the qdo tool (top)
# net (the LibTorch plugin, qdo_net) sits on decode and below, and nothing in the core includes it.
# data may use runtime, and runtime nothing above it; decode may use physics, data and runtime; etc.
#
# Checks, for every file of src/<folder>/ and include/qdo/<folder>/ (a public header's layer is its
# folder, the folder of src/ that defines its functions; a private header "<folder>/x.hpp" is <folder>'s):
#   1. every #include "qdo/<folder>/X.hpp" / "<folder>/x.hpp" names a header of the same or a lower layer;
#   2. every public header lies in the folder of a layer (none directly in include/qdo/);
#   3. a .cpp whose first include is its own header (the header's name begins its file name, as
#      wiener.cpp / wiener.hpp, camera_skip.cpp / camera.hpp) lies in that header's folder.
# And, once the includes pass, for the code and documentation (src include tests bench docs scripts
# python fuzz examples, README.md, BENCHMARKS.md, STABILITY.md, CMakeLists.txt):
#   4. no project-internal issue number (the word issue or issues, then a number, as in "issue #N"),
#      which a reader cannot look up: comments and docs say what the code does today;
#   5. no "../shared" path in src/ or include/ (datasets come through the data root).
# Prints each violation and exits 1 when there is one. Usage: scripts/check_layers.sh [REPO]
set -euo pipefail
cd "${1:-$(dirname "$0")/..}"

# folder -> the folders it may include from
allowed='
runtime runtime
data runtime,data
physics runtime,data,physics
decode runtime,data,physics,decode
net runtime,data,physics,decode,net
design runtime,data,physics,decode,design
evaluate runtime,data,physics,decode,design,evaluate
asbuilt runtime,data,physics,decode,design,asbuilt
cli runtime,data,physics,decode,design,evaluate,asbuilt,fab,cli
fab runtime,data,physics,decode,design,evaluate,asbuilt,fab
'

shopt -s nullglob
files=(src/*/*.cpp src/*/*.hpp include/qdo/*/*.hpp)
bad=0
for h in include/qdo/*.hpp; do
  echo "$h: a public header outside the layer folders (include/qdo/<layer>/, the layer of the src/ folder that defines it)"
  bad=1
done
for d in include/qdo/*/; do
  layer=$(basename "$d")
  if ! grep -q "^$layer " <<< "$allowed"; then echo "$d: not a layer (one of: $(awk 'NF == 2 { printf "%s ", $1 }' <<< "$allowed"))"; bad=1; fi
done
((bad == 0)) || { echo "layers: violations found"; exit 1; }
{
  echo "ALLOWED"; echo "$allowed"
  echo "INCLUDES"; grep -H '^#include "' "${files[@]}" || true
} | awk '
  /^ALLOWED$/ { mode = "a"; next }
  /^INCLUDES$/ { mode = "i"; next }
  mode == "a" && NF == 2 { n = split($2, f, ","); for (k = 1; k <= n; ++k) ok[$1 "," f[k]] = 1; layer[$1] = 1; next }
  mode == "i" {
    file = $0; sub(/:.*/, "", file)
    inc = $0; sub(/^[^"]*"/, "", inc); sub(/".*/, "", inc)
    # the layer of the including file: its folder under include/qdo/ or src/
    from = file; sub(/^include\/qdo\//, "", from); sub(/^src\//, "", from); sub(/\/.*/, "", from)
    # the layer of the included header
    if (inc ~ /^qdo\//) {
      if (inc !~ /^qdo\/[a-z]+\/[a-z0-9_]+\.hpp$/) { print file ": includes " inc ", not a header of a layer folder (qdo/<layer>/x.hpp)"; bad = 1; next }
      to = inc; sub(/^qdo\//, "", to); h = to; sub(/\/.*/, "", to); sub(/^[a-z]+\//, "", h); sub(/\.hpp$/, "", h)
      if (!(to in layer)) { print file ": includes " inc ", whose folder is not a layer"; bad = 1; next }
      if (system("test -f include/" inc) != 0) { print file ": includes " inc ", which does not exist"; bad = 1; next }
      # 3. a .cpp implementing its own header lies in the header s folder
      if (file ~ /\.cpp$/ && !(file in seen)) {
        base = file; sub(/^.*\//, "", base); sub(/\.cpp$/, "", base)
        if ((base == h || index(base, h "_") == 1) && to != from) {
          print file ": implements include/" inc ", whose functions belong in src/" to "/"; bad = 1
        }
      }
    } else if (inc ~ /^[a-z_]+\/[a-z_]+\.hpp$/) {
      to = inc; sub(/\/.*/, "", to)
    } else {
      seen[file] = 1; next  # a header beside the file ("cli.hpp")
    }
    seen[file] = 1
    if (!((from "," to) in ok)) {
      print file " (" from "): includes " inc " (" to "), a higher layer"; bad = 1
    }
    next
  }
  END {
    if (bad) { print "layers: violations found (runtime, data < physics < decode < design < fab < cli; net on decode)"; exit 1 }
    print "layers: every include points down"
  }
'

# 4. No project-internal issue numbers. The word must stand alone (not part of another word) and
# not follow a "/", so a link to an upstream tracker (github.com/OWNER/REPO/issues/N) is no hit.
issue_paths=()
for p in src include tests bench docs scripts python fuzz examples README.md BENCHMARKS.md STABILITY.md EXPERIMENTS.md EXPERIMENTS_FAB.md kernels CMakeLists.txt; do
  [[ -e $p ]] && issue_paths+=("$p")
done
rc=0
hits=$(grep -rnIE '(^|[^[:alnum:]_/])[Ii]ssues? ?#?[0-9]+' "${issue_paths[@]}") || rc=$?
if (( rc == 0 )); then
  echo "$hits"
  echo "layers: issue numbers found (say what the code does instead of citing an internal issue)"
  exit 1
elif (( rc > 1 )); then
  echo "layers: grep failed ($rc) while looking for issue numbers"
  exit 1
fi
echo "layers: no internal issue numbers in the code and docs"

# 5. No path relative to the working directory into the shared data in the library or the tool:
# datasets are found through the data root (include/qdo/data/data_root.hpp).
rc=0
hits=$(grep -rnI '\.\./shared' src include) || rc=$?
if (( rc == 0 )); then
  echo "$hits"
  echo "layers: a ../shared path in src/ or include/ (use the data root: dataset names, qdo data)"
  exit 1
elif (( rc > 1 )); then
  echo "layers: grep failed ($rc) while looking for ../shared paths"
  exit 1
fi
echo "layers: no ../shared path in src/ or include/"
