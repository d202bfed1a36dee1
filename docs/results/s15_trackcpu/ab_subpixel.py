"""Call-by-call A/B of a ``canopy.frontend.stereo`` function (``--func``: subpixel_refine,
match_stereo, stereo_candidates): another checkout's (``--base``) against this one's, on recorded
KITTI calls (``record_calls.py``), alternating which goes first call by call; thread CPU per call
and bit-identity of every output array (StereoMatches: u_right, depth).

    PYTHONPATH=$PWD python docs/results/s15_trackcpu/ab_subpixel.py --base /tmp/s15t/base --calls /tmp/s15t/calls_kitti.pkl --reps 3
    PYTHONPATH=$PWD python docs/results/s15_trackcpu/ab_subpixel.py --base /tmp/s15t/base --func match_stereo --calls /tmp/s15t/ms_kitti.pkl
"""
import argparse
import importlib.util
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from canopy.frontend import stereo  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--base", type=Path, required=True)
ap.add_argument("--calls", type=Path, required=True)
ap.add_argument("--reps", type=int, default=3)
ap.add_argument("--func", default="subpixel_refine")
a = ap.parse_args()
spec = importlib.util.spec_from_file_location("base_stereo", a.base / "canopy/frontend/stereo.py")
base = importlib.util.module_from_spec(spec)
sys.modules["base_stereo"] = base
spec.loader.exec_module(base)
calls = pickle.load(open(a.calls, "rb"))
t = {"base": [], "this": []}
same = 0
fb, fn = getattr(base, a.func), getattr(stereo, a.func)


def arrays(out):
    return (out.u_right, out.depth) if hasattr(out, "u_right") else out


for rep in range(a.reps):
    for i, (args, kw) in enumerate(calls):
        order = (("base", fb), ("this", fn))
        if (i + rep) % 2:
            order = order[::-1]
        out = {}
        for name, f in order:  # (a PairPyramids argument is duck-typed: either module's serves both)
            c0 = time.thread_time()
            out[name] = arrays(f(*args, **kw))
            t[name].append((time.thread_time() - c0) * 1e3)
        same += all(np.array_equal(x, y) and x.dtype == y.dtype
                    and np.array_equal(np.signbit(x), np.signbit(y)) for x, y in zip(out["base"], out["this"]))
b, n = np.array(t["base"]), np.array(t["this"])
print(f"{a.func}, {len(calls)} calls x {a.reps}: base p50 {np.median(b):.3f} mean {b.mean():.3f} ms; "
      f"this p50 {np.median(n):.3f} mean {n.mean():.3f} ms; ratio p50 {np.median(n) / np.median(b):.3f} "
      f"mean {n.mean() / b.mean():.3f}; identical {same}/{len(calls) * a.reps}")
