"""s32: the clean KITTI frames tracked with the FAST arguments the enhancement rule hands for a degraded cell's
frames (key=value overrides them; key=drop removes one). Shows what those arguments cost on frames with no noise.

    PYTHONPATH=$PWD python docs/results/s32_oracle/clean_frames_cell_args.py CELL [fast_threshold=20 ...]
"""
import sys
from pathlib import Path
from canopy.frontend import Tracker
from canopy.sources import BUNDLED_DATA, open_source
from shared.types import StereoFrame
clean = open_source("kitti", BUNDLED_DATA["kitti"])
override = sys.argv[2:]
orig = Tracker.track
def track(self, frame, *a, **k):
    c = clean.frame(frame.index)
    for o in override:
        key, v = o.split('=')
        if v == 'drop': k.pop(key, None)
        else: k[key] = int(v)
    return orig(self, StereoFrame(frame.index, frame.timestamp, c.left, c.right), *a, **k)
Tracker.track = track
from benchmarks.bench_enhance_diagnose import run
res, rows = run(Path(sys.argv[1]), BUNDLED_DATA["kitti"], "kitti", {"method": "auto"}, {}, None, stereo=False, kind="kitti")
print('clean frames, args of', Path(sys.argv[1]).name, override, 'ate %.1f sim3 %.1f scale %.4f'%(res['ate']*1e3,res['ate_sim3']*1e3,res['scale']))
