#!/bin/bash
# Generation speed before/after: bash notes/speed_bench.sh MINUTES BEFORE_SRC AFTER_SRC
#   BEFORE_SRC: src/ of a v0.1 checkout (SUMO command line + FCD), AFTER_SRC: src/ of this branch.
# Prints wall/CPU (user+sys incl. children)/max RSS per run (GNU time), 3 interleaved repetitions,
# and the speed line letspi data generate prints itself. Run inside the project's venv.
set -euo pipefail
M=${1:-10}; BEFORE=${2:?BEFORE_SRC}; AFTER=${3:?AFTER_SRC}
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
for rep in 1 2 3; do
  echo "load: $(cut -d' ' -f1-3 /proc/loadavg)"
  /usr/bin/time -f "v0.1 rep$rep: %e s wall, %U s user, %S s sys, %M KB maxrss" \
    env PYTHONPATH="$BEFORE" letspi data generate --out "$WORK/v01_$rep" --minutes "$M" --seed 0 2>&1 | grep -E "^v0.1"
  for p in calm highd; do
    /usr/bin/time -f "$p rep$rep: %e s wall, %U s user, %S s sys, %M KB maxrss" \
      env PYTHONPATH="$AFTER" letspi data generate --out "$WORK/${p}_$rep" --minutes "$M" --seed 0 \
      --criticality "$p" 2>&1 | grep -E "^$p rep|speed|stepping|warm-up" | tr '\n' ' '
    echo
  done
done
