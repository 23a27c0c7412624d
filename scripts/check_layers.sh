#!/usr/bin/env bash
# The layers of src/ point down only (CTest entry "layers"). From the bottom:
#   runtime, data          OpenCL, FFT, kernel cache; configurations, scenes, files, materials
#   physics                the optical stages and their CPU references
#   decode                 decoders and their registry, the test-set evaluation
#   design                 the optimiser, run folders, eval of a run, sweeps
#   fab                    fabrication export and tolerance
#   cli                    the qdo tool (top)
# net (the LibTorch plugin, qdo_net) sits on decode and below, and nothing in the core includes it.
# data may use runtime, and runtime nothing above it; decode may use physics, data and runtime; etc.
#
# Checks, for every file of src/<folder>/ and include/qdo/ (a public header belongs to the folder
# that defines its functions, per the table below; a private header "<folder>/x.hpp" to <folder>):
#   1. every #include "qdo/X.hpp" / "<folder>/x.hpp" names a header of the same or a lower layer;
#   2. every public header is in the table, and every table entry exists;
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

# public header -> the folder that defines its functions (header-only headers: runtime)
table='
adjoint physics
camera physics
camera_reference physics
calibrate physics
config data
cpu_reference physics
datasets data
data_root data
figure data
decoder decode
decoder_registry decode
decoder_spec decode
demosaic physics
demosaic_reference physics
design design
design_run design
design_run_options design
doe physics
doe_adjoint_reference physics
embedded runtime
encoders decode
error runtime
eval design
eval_points design
fab fab
fft runtime
fftw2 runtime
field physics
flat_field physics
field_reference physics
gds fab
fit design
gradcheck design
hash runtime
host_propagator runtime
io data
io_raw data
joint design
joint_sampling design
kernel_cache runtime
materials data
mpi runtime
net net
network_decoder decode
optics physics
propagate physics
propagate_reference physics
psf physics
psf_metrics physics
psf_reference physics
psf_source physics
psf_spec design
point_psf physics
reconstruct design
radial physics
recipe design
release physics
release_reference physics
resunet net
rng runtime
run design
run_folder design
runtime runtime
scenes data
raw physics
raw_reference physics
sensor physics
sensor_reference physics
simulator physics
sweep design
sweep_stats design
testset decode
types runtime
util runtime
varying physics
varying_reference physics
wiener decode
wiener_device decode
'

# folder -> the folders it may include from
allowed='
runtime runtime
data runtime,data
physics runtime,data,physics
decode runtime,data,physics,decode
net runtime,data,physics,decode,net
design runtime,data,physics,decode,design
cli runtime,data,physics,decode,design,fab,cli
fab runtime,data,physics,decode,design,fab
'

shopt -s nullglob
files=(src/*/*.cpp src/*/*.hpp include/qdo/*.hpp)
{
  echo "TABLE"; echo "$table"
  echo "ALLOWED"; echo "$allowed"
  echo "HEADERS"; for h in include/qdo/*.hpp; do basename "$h" .hpp; done
  echo "INCLUDES"; grep -H '^#include "' "${files[@]}" || true
} | awk '
  /^TABLE$/ { mode = "t"; next }
  /^ALLOWED$/ { mode = "a"; next }
  /^HEADERS$/ { mode = "h"; next }
  /^INCLUDES$/ { mode = "i"; next }
  mode == "t" && NF == 2 { folder[$1] = $2; next }
  mode == "a" && NF == 2 { n = split($2, f, ","); for (k = 1; k <= n; ++k) ok[$1 "," f[k]] = 1; next }
  mode == "h" && NF == 1 { present[$1] = 1; next }
  mode == "i" {
    file = $0; sub(/:.*/, "", file)
    inc = $0; sub(/^[^"]*"/, "", inc); sub(/".*/, "", inc)
    # the layer of the including file
    if (file ~ /^include\/qdo\//) { h = file; sub(/^include\/qdo\//, "", h); sub(/\.hpp$/, "", h); from = folder[h] }
    else { from = file; sub(/^src\//, "", from); sub(/\/.*/, "", from) }
    if (from == "") next  # a header missing from the table is reported below
    # the layer of the included header
    if (inc ~ /^qdo\//) {
      h = inc; sub(/^qdo\//, "", h); sub(/\.hpp$/, "", h)
      if (!(h in folder)) { print file ": includes " inc ", which the table in scripts/check_layers.sh does not place"; bad = 1; next }
      to = folder[h]
      # 3. a .cpp implementing its own header lies in the header s folder
      if (file ~ /\.cpp$/ && !(file in seen)) {
        base = file; sub(/^.*\//, "", base); sub(/\.cpp$/, "", base)
        if ((base == h || index(base, h "_") == 1) && to != from) {
          print file ": implements include/qdo/" h ".hpp, whose functions the table places in src/" to "/"; bad = 1
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
    for (h in present) if (!(h in folder)) { print "include/qdo/" h ".hpp: not in the table of scripts/check_layers.sh"; bad = 1 }
    for (h in folder) if (!(h in present)) { print "scripts/check_layers.sh: the table names include/qdo/" h ".hpp, which does not exist"; bad = 1 }
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
# datasets are found through the data root (include/qdo/data_root.hpp).
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
