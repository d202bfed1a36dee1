"""Record the KITTI tracker's ``subpixel_refine`` calls (or ``--func match_stereo``'s) to a pickle, for call-by-call A/B.

    PYTHONPATH=$PWD python docs/results/s15_trackcpu/record_calls.py --dataset kitti --out /tmp/s15t/calls_kitti.pkl
"""
import argparse
import pickle
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend import Tracker, stereo, tracker_worker  # noqa: E402
from canopy.sources import open_source  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--dataset", default="kitti")
ap.add_argument("--out", type=Path, required=True)
ap.add_argument("--func", default="subpixel_refine", choices=["subpixel_refine", "match_stereo"])
a = ap.parse_args()
src = open_source(a.dataset, None)
calls = []
mod = stereo if a.func == "subpixel_refine" else tracker_worker
orig = getattr(mod, a.func)


def rec(*args, **kw):
    calls.append((args, kw))
    return orig(*args, **kw)


setattr(mod, a.func, rec)
cfg = load_run_config(a.dataset)
tracker = Tracker(src.calibration, cfg.tracking)
for i in range(len(src)):
    tracker.track(src.frame(i))
a.out.parent.mkdir(parents=True, exist_ok=True)
with open(a.out, "wb") as f:
    pickle.dump(calls, f)
print(len(calls), "calls")
