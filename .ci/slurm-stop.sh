#!/usr/bin/env bash
# Stop the SLURM daemons that .ci/slurm-start.sh started, and only those: it listed their pid
# files in STATE_DIR/started (slurmd first, then slurmctld, then munged: the reverse order).
# Usage: .ci/slurm-stop.sh [STATE_DIR]   (default ${FEM_RMPM_SLURM_STATE:-/tmp/fem-rmpm-slurm})
set -uo pipefail
S=${1:-${FEM_RMPM_SLURM_STATE:-/tmp/fem-rmpm-slurm}}
[ -f "$S/started" ] || exit 0
rc=0
for pidfile in $(tac "$S/started"); do
  [ -s "$pidfile" ] || { echo "slurm-stop: $pidfile missing; nothing to stop" >&2; continue; }
  pid=$(cat "$pidfile")
  kill -0 "$pid" 2>/dev/null || continue
  kill -TERM "$pid"
  for _ in $(seq 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done   # <= 10 s
  if kill -0 "$pid" 2>/dev/null; then
    echo "slurm-stop: pid $pid ($pidfile) still runs after 10 s; sending KILL" >&2
    kill -KILL "$pid" 2>/dev/null; rc=1
  fi
done
: > "$S/started"
exit $rc
