#!/bin/bash
# Local mapping outside the solver, base and this checkout alternately (one process at a time, thread CPU):
#   docs/results/s19_obsstore/alternate.sh REC ROUNDS REPS BASE_ROOT THIS_ROOT
# REC: a recording of benchmarks/ab_mapping.py (--recording) or record_hover.py. Each line: per rep, ms per keyframe.
HERE=$(cd "$(dirname "$0")" && pwd)
REC=$1; ROUNDS=$2; REPS=$3; BASE=$4; THIS=$5
for r in $(seq "$ROUNDS"); do
  for side in base this; do
    root=$BASE; [ $side = this ] && root=$THIS
    (cd "$root" && PYTHONPATH=$root python "$HERE/outside_solver.py" "$REC" "$REPS" 2>/dev/null | sed "s/^/$side /")
  done
done
