# shellcheck shell=bash
# Sourced by the experiment scripts: the environment they run in and the one folder they write.
#   claim_out NAME OUT   OUT becomes NAME's output folder. The script deletes and rewrites only the
#                        folders it makes under OUT; an OUT it did not make (no OUT/.NAME marker) is
#                        refused with exit 2, so a user's folder is never touched.
export QDO_DEVICE=${QDO_DEVICE:-cpu}
export QDO_CACHE_DIR=${QDO_CACHE_DIR:-$PWD/build/kernel-cache}
claim_out() {
  local name=$1 out=$2
  if [ -e "$out" ] && [ ! -f "$out/.$name" ]; then
    echo "$name: $out exists and was not made by this script (no $out/.$name); choose another OUT" >&2
    exit 2
  fi
  mkdir -p "$out"
  touch "$out/.$name"
}
log() { printf '\n== %s\n' "$*"; }
