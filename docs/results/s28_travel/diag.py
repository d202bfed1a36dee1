"""s28-travel: one KITTI cell through bench_enhance_diagnose's in-process loop (the grid's runner) with
tracking settings over configs/kitti.yaml; prints tracked share, ATE, Sim(3) ATE and scale as JSON, and the
rms of the per-frame step error against ground truth.

    python docs/results/s28_travel/diag.py PATH [travel_direction_sigma_deg=0 ...]
"""
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
import benchmarks.bench_enhance_diagnose as bed  # noqa: E402
from canopy.config import parse_value  # noqa: E402

path = sys.argv[1]
sets = {k.split('.', 1)[-1]: parse_value(v) for k, v in (a.split('=', 1) for a in sys.argv[2:])}
out, rows = bed.run(path, bed.BUNDLED_DATA['kitti'], 'kitti', {}, sets, stereo=False)
dt = [r['dt_err'] for r in rows if 'dt_err' in r]
print(json.dumps({k: out[k] for k in ('tracked', 'ate', 'ate_sim3', 'scale') if k in out}),
      'step_rms_mm %.1f' % (1000 * np.sqrt(np.mean(np.square(dt)))))
