#!/usr/bin/env bash
# A new user's first results, timed: each in a scratch clone of this
# repository with empty caches (pip, httpstan, stancal), on this machine.
#   1. ./run demo: venv, install, compiles, calibration and gap report (target 5 min)
#   2. ./run calibrate case_studies/cooling/config.toml: venv, install,
#      compile, first posterior (target 2.5 min, issue 30)
#     benchmarks/first_run.sh [demo|calibrate]   (default: both)
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
which="${1:-both}"

fresh_clone() {  # echo the folder of a scratch clone whose caches are empty
  local scratch
  scratch="$(mktemp -d /tmp/stancal_first_run.XXXXXX)"
  git clone -q "$repo" "$scratch/stancal"
  echo "$scratch"
}

timed() {  # timed LABEL TARGET_SECONDS SCRATCH COMMAND...: run in the clone, print seconds against target
  local label="$1" target="$2" scratch="$3"; shift 3
  local started ended status=0
  started=$(date +%s.%N)
  (cd "$scratch/stancal" && XDG_CACHE_HOME="$scratch/cache" STANCAL_CACHE= "$@") \
      > "$scratch/output.log" 2>&1 || status=$?
  ended=$(date +%s.%N)
  local seconds
  seconds=$(python3 -c "print(round($ended - $started))")
  printf '%-48s %5s s   target %4s s   %s   (log: %s)\n' "$label" "$seconds" "$target" \
      "$([ "$status" -eq 0 ] && { [ "$seconds" -le "$target" ] && echo met || echo MISSED; } || echo "FAILED ($status)")" \
      "$scratch/output.log"
  grep -h "set-up\|compiled\|sampled in\|^gap:\|^koh\|^modular\|^Time:" "$scratch/output.log" \
      "$scratch"/stancal/*/report.md 2>/dev/null | sed 's/^/    /' || true
}

if [ "$which" = demo ] || [ "$which" = both ]; then
  scratch="$(fresh_clone)"
  timed "fresh clone: ./run demo (full gap report)" 300 "$scratch" ./run demo
fi
if [ "$which" = calibrate ] || [ "$which" = both ]; then
  scratch="$(fresh_clone)"
  timed "fresh clone: ./run calibrate (cooling)" 150 "$scratch" \
      ./run calibrate case_studies/cooling/config.toml --out first_posterior
fi
