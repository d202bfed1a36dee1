# s32: a setting over a cell's seeds: sweep.sh "CELL-with-{s}" "0 1 2" [section.field=value ...] (RUNNER: another runner script)
# usage: sweep.sh CELLPREFIX(with {s}) SEEDS -- settings...
pre=$1; seeds=$2; shift 2
for s in $seeds; do python ${RUNNER:-docs/results/s32_oracle/cell_run.py} ${pre//\{s\}/$s} "$@"; done | python -c "
import sys,json
rows=[json.loads(l) for l in sys.stdin if l.startswith('{')]
v=[r['ate_mm'] for r in rows]; sc=[r['scale'] for r in rows]; tr=[r['tracked'] for r in rows]
print(' '.join(sys.argv[1:]), '|', ' '.join('%.1f'%x for x in v), '| mean %.1f'%(sum(v)/len(v)), '| scale', ' '.join('%.4f'%x for x in sc), '| tracked min %.3f'%min(tr))
" "$pre" "$@"
