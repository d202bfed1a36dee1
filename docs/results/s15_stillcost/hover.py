"""A long hover: the still EuRoC snippet played forth and back (ping-pong) for REPS passes, in process as the
grid runs it, to see whether local mapping's CPU per keyframe keeps growing (docs/notes/s15-stillcost.md).

Throw-away measurement script, run from the worktree root:
    REPS=4 CELL=g1-b0.06-low python docs/results/s15_stillcost/hover.py [tracking.x=v] [mapping.y=v] ...
The MAV hangs still, so the reversed passes are the same hover (ground truth taken from the frames played).
Prints mapcost.py's summary with the keyframes split in sixths.
"""
import dataclasses, os, runpy, sys
sys.path.insert(0, os.getcwd())
import benchmarks.bench_enhance_diagnose as bed
from shared.types import Trajectory

REPS = int(os.environ.get("REPS", "4"))
_open = bed.open_source


class PingPong:
    def __init__(self, src):
        self.src, n = src, len(src)
        self.order = [i if (p % 2 == 0) else n - 1 - i for p in range(REPS) for i in range(n)]
        self.calibration = src.calibration
        gt = src.ground_truth
        dt = float(gt.stamps[1] - gt.stamps[0])
        self.ground_truth = Trajectory(gt.stamps[0] + dt * __import__("numpy").arange(len(self.order)),
                                       gt.poses[self.order])
        self._dt, self._t0 = dt, float(gt.stamps[0])

    def __len__(self):
        return len(self.order)

    def frame(self, i):
        fr = self.src.frame(self.order[i])
        return dataclasses.replace(fr, index=i, timestamp=self._t0 + self._dt * i)


bed.open_source = lambda *a, **k: PingPong(_open(*a, **k))
os.environ.setdefault("SIXTHS", "1")
runpy.run_path("docs/results/s15_stillcost/mapcost.py", run_name="__main__")
