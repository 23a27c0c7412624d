#!/usr/bin/env bash
# Times `scripts/install-deps.sh SET` on a fresh machine, phase by phase, from apt's own output:
# every line it prints is stamped with the time it arrived, and the phases are read from them:
#   update + download   start -> the first "Unpacking" line (apt-get update, the downloads, dpkg's
#                       database read)
#   unpack              -> the first "Setting up" line after the last "Unpacking"
#   configure           -> the end (dpkg's maintainer scripts and the ldconfig, man-db and Python
#                       byte-compiling triggers)
# Writes OUT/install_times.md (the phases, the package count, the machine and the date) and
# OUT/install.log (the stamped output). On a machine where every package of SET is present it
# says so and times nothing: only a fresh machine answers the question.
#
# Usage: bench/time_install.sh OUT [SET=all]     (SET: all or core, as install-deps.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:?usage: bench/time_install.sh OUT [all|core]}
SET=${2:-all}
case "$SET" in all|core) ;; *) echo "time_install.sh: SET=$SET: all or core" >&2; exit 2 ;; esac
mkdir -p "$OUT"
log="$OUT/install.log.tmp"
t0=$(date +%s.%N)
# Each line with its arrival time in seconds since the start.
bash scripts/install-deps.sh "$SET" 2>&1 | while IFS= read -r line; do
  printf '%.2f %s\n' "$(echo "$(date +%s.%N) - $t0" | bc)" "$line"
done > "$log"
t_end=$(echo "$(date +%s.%N) - $t0" | bc)
mv "$log" "$OUT/install.log"
if grep -q "all packages present" "$OUT/install.log"; then
  echo "time_install: every package of '$SET' is already installed here; nothing to time (run it on a fresh machine)"
  exit 0
fi
# apt prints "Unpacking" and "Setting up" once per package; lines may hold several records
# (progress text without newlines), so count the records, not the lines.
read -r first_unpack last_unpack packages first_setup < <(awk '
  { t = $1; n = gsub(/Unpacking /, "&"); if (n > 0) { if (fu == "") fu = t; lu = t; count += n }
    if (/Setting up /) setup[++ns] = t }
  END { for (i = 1; i <= ns; ++i) if (setup[i] >= lu) { fs = setup[i]; break }
        print fu, lu, count, fs }' "$OUT/install.log")
{
  echo "# scripts/install-deps.sh $SET on a fresh machine"
  echo
  echo "$(date -u +"%Y-%m-%d %H:%M UTC"); $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'); $packages packages unpacked."
  echo
  echo "| phase | s |"
  echo "|---|---:|"
  echo "| update + download (to the first unpack) | $first_unpack |"
  echo "| unpack (to the first configure after the last unpack) | $(echo "$first_setup - $first_unpack" | bc) |"
  echo "| configure (maintainer scripts, triggers) | $(echo "$t_end - $first_setup" | bc) |"
  echo "| **whole install** | **$t_end** |"
} > "$OUT/install_times.md.tmp"
mv "$OUT/install_times.md.tmp" "$OUT/install_times.md"
cat "$OUT/install_times.md"
