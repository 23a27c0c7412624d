#!/usr/bin/env bash
# What a fresh machine pays for qdo's Debian packages before the first build: the packages that
# scripts/install-deps.sh SET pulls in (its names and their Depends/Pre-Depends, recursively) that
# the machine image does not have, their download size and time, and the time to unpack them.
#
# Usage: bench/setup_packages.sh BASE_LIST OUT [SET=all]
#   BASE_LIST  the fresh image's package list: one package a line, "NAME" or "apt<TAB>NAME<TAB>VERSION"
#              (the second form is how the machine image's list is kept)
#   OUT        a folder for the report (OUT/setup_packages.md) and the list of packages (OUT/new.txt)
# Nothing is installed: the .deb files are downloaded with `apt-get download` and unpacked with
# `dpkg-deb -x` into a temporary folder in OUT, removed at the end. Not timed: dpkg's configure step (maintainer scripts,
# triggers such as ldconfig and Python byte-compiling) and `apt-get update`. The download time
# depends on the mirror and the network of the moment: the report names the date and the machine.
set -euo pipefail
cd "$(dirname "$0")/.."
BASE=${1:?usage: bench/setup_packages.sh BASE_LIST OUT [SET]}
OUT=${2:?usage: bench/setup_packages.sh BASE_LIST OUT [SET]}
SET=${3:-all}
[ -r "$BASE" ] || { echo "setup_packages.sh: BASE_LIST '$BASE' is not a readable file" >&2; exit 2; }
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
# The downloads and the unpacked tree go to a folder of this run's own, removed when it ends.
W=$(mktemp -d "$OUT/setup_packages.XXXXXX")
trap 'rm -rf "$W"' EXIT
mkdir -p "$W/debs" "$W/root"

mapfile -t wanted < <(bash scripts/install-deps.sh --list "$SET")
# The closure: real packages only (virtual ones print as <name>), the machine's architecture.
apt-cache depends --recurse --no-recommends --no-suggests --no-conflicts --no-breaks --no-replaces --no-enhances \
  "${wanted[@]}" 2>/dev/null | grep -E '^[a-z0-9]' | sed 's/:.*$//' | sort -u > "$W/closure.txt"
awk -F'\t' 'NF >= 2 { print $2; next } /^[a-z0-9]/ { print $1 }' "$BASE" | sed 's/:.*$//' | sort -u > "$W/base.txt"
# apt-cache lists both sides of "Depends: a | b"; apt installs one. Where this machine has the set
# installed, the closure is cut to what apt chose here; on a machine without it, it stays an upper bound.
dpkg-query -W -f='${Package} ${Status}\n' 2>/dev/null | awk '$NF == "installed" { print $1 }' | sed 's/:.*$//' | sort -u > "$W/here.txt"
chosen="the closure cut to the packages apt chose on this machine"
if ! comm -23 <(printf '%s\n' "${wanted[@]}" | sort -u) "$W/here.txt" | grep -q .; then
  comm -12 "$W/closure.txt" "$W/here.txt" > "$W/closure_chosen.txt"
else
  cp "$W/closure.txt" "$W/closure_chosen.txt"
  chosen="the whole closure, both sides of every alternative (the set is not installed here): an upper bound"
fi
comm -23 "$W/closure_chosen.txt" "$W/base.txt" > "$OUT/new.txt"
n=$(wc -l < "$OUT/new.txt")
[ "$n" -gt 0 ] || { echo "setup_packages.sh: the image has every package of set $SET" >&2; exit 0; }

t0=$(date +%s.%N)
(cd "$W/debs" && xargs -a "$OUT/new.txt" apt-get download -qq > "$OUT/download.log" 2>&1) ||
  { echo "setup_packages.sh: apt-get download failed (see $OUT/download.log)" >&2; exit 1; }
t1=$(date +%s.%N)
for d in "$W"/debs/*.deb; do dpkg-deb -x "$d" "$W/root"; done
t2=$(date +%s.%N)

mb=$(du -sm "$W/debs" | cut -f1)
unpacked_mb=$(du -sm "$W/root" | cut -f1)
got=$(find "$W/debs" -name '*.deb' | wc -l)
largest=$(find "$W/debs" -name '*.deb' -printf '%s %f\n' | sort -rn | head -5 | awk '{ printf "%s (%.0f MB), ", $2, $1 / 1048576 }' | sed 's/, $//')
cpu=$(lscpu | sed -n 's/^Model name: *//p' | head -1)
{
  echo "# A fresh machine's packages for qdo (install-deps.sh $SET)"
  echo
  echo "- date: $(date -u +'%Y-%m-%d %H:%M UTC'); machine: $cpu, $(nproc) cores; base list: $(basename "$BASE")"
  echo "- packages named by install-deps.sh: ${#wanted[@]}; with their dependencies: $(wc -l < "$W/closure_chosen.txt") ($chosen); not in the image: $n (downloaded: $got)"
  echo "- download: $mb MB in $(printf '%.0f' "$(echo "$t1 - $t0" | bc)") s (\`apt-get download\`, one connection)"
  echo "- unpack: $unpacked_mb MB in $(printf '%.0f' "$(echo "$t2 - $t1" | bc)") s (\`dpkg-deb -x\` one after another)"
  echo "- largest: $largest"
  echo "- not timed: dpkg's configure step (maintainer scripts, ldconfig and Python byte-compiling triggers), apt-get update"
} > "$OUT/setup_packages.md"
cat "$OUT/setup_packages.md"
