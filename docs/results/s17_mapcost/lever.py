"""A mapping / keyframe lever, in process (the grid runner's loop: benchmarks/bench_enhance_diagnose.run,
auto enhancement, map updates as the actors' lockstep applies them): ATE, keyframes, their reasons and
local mapping's thread CPU per frame and per keyframe.

    PYTHONPATH=$PWD python docs/results/s17_mapcost/lever.py --dataset kitti [--set tracking.x=v] [--set mapping.y=v] [--path P]
"""
import argparse, json, sys, time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from benchmarks.bench_enhance_diagnose import run  # noqa: E402
from canopy.backend import LocalMapper  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.config import parse_value  # noqa: E402
from canopy.sources import BUNDLED_DATA  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--dataset", default="kitti")
ap.add_argument("--path", default=None)
ap.add_argument("--set", action="append", default=[])
ap.add_argument("--label", default="")
ap.add_argument("--json", default=None, help="append the result as one JSON line")
a = ap.parse_args()
track, mapping = {}, {}
for s in a.set:
    k, v = s.split("=", 1)
    sec, key = k.split(".")
    (track if sec == "tracking" else mapping)[key] = parse_value(v)

map_cpu, reasons = [], Counter()
ins, trk = LocalMapper.insert_keyframe, Tracker.track


def insert(self, kf):
    t0 = time.thread_time()
    u = ins(self, kf)
    map_cpu.append((time.thread_time() - t0) * 1e3)
    return u


def track_(self, frame, *args, **kw):
    res = trk(self, frame, *args, **kw)
    if res.is_keyframe and res.keyframe is not None:
        reasons.update((res.keyframe_reason or "init").split("+"))
    return res


LocalMapper.insert_keyframe, Tracker.track = insert, track_
path = a.path or BUNDLED_DATA[a.dataset]
out, rows = run(path, BUNDLED_DATA[a.dataset], a.dataset, {"method": "auto"}, track, stereo=False, kind=a.dataset,
                map_sets=mapping)
n = len(rows)
res = {"label": a.label, "dataset": a.dataset, "path": str(path), "sets": a.set, "ate_m": out.get("ate"),
       "tracked": out["tracked"], "frames": n, "keyframes": len(map_cpu), "reasons": dict(reasons),
       "map_cpu_ms_per_frame": sum(map_cpu) / n, "map_cpu_ms_per_kf": sum(map_cpu) / max(len(map_cpu), 1)}
print(json.dumps(res))
if a.json:
    with open(a.json, "a") as f:
        f.write(json.dumps(res) + "\n")
