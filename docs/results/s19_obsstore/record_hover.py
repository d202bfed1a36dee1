"""Record a clean EuRoC hover for benchmarks/ab_mapping.py's replay: the bundled snippet played forth and back
(ping-pong) REPS passes (default 5: 475 frames, 159 keyframes), as docs/results/s15_stillcost/hover.py but undegraded.

    REPS=5 PYTHONPATH=$PWD python docs/results/s19_obsstore/record_hover.py /tmp/rec_hover.pkl
"""
import dataclasses, os, sys
from pathlib import Path
sys.path.insert(0, os.getcwd()); sys.path.insert(0, os.path.join(os.getcwd(), "benchmarks"))
import canopy.sources as cs
REPS = int(os.environ.get("REPS", "5"))
_open = cs.open_source

class PingPong:
    def __init__(self, src):
        self.src, n = src, len(src)
        self.order = [i if p % 2 == 0 else n - 1 - i for p in range(REPS) for i in range(n)]
        self.calibration = src.calibration
        gt = src.ground_truth
        self._dt, self._t0 = float(gt.stamps[1] - gt.stamps[0]), float(gt.stamps[0])
    def __len__(self): return len(self.order)
    def frame(self, i):
        fr = self.src.frame(self.order[i])
        return dataclasses.replace(fr, index=i, timestamp=self._t0 + self._dt * i)

cs.open_source = lambda *a, **k: PingPong(_open(*a, **k))
import ab_mapping
ab_mapping.record("euroc", Path(sys.argv[1]))
