"""Replay a recording (benchmarks/ab_mapping.py) in the checkout on PYTHONPATH: thread CPU per keyframe of
insert_keyframe, of local BA's solver (bundle_adjust_points, unchanged code) and of the rest (outside the solver)."""
import pickle, sys, time
import canopy.backend.local_ba as lba
from canopy.backend import LocalMapper
from canopy.config import load_run_config
rec = pickle.load(open(sys.argv[1], "rb")); reps = int(sys.argv[2])
params = load_run_config(rec["dataset"]).mapping
kfs = [pickle.loads(b) for b in rec["keyframes"]]
solve = lba.bundle_adjust_points; lm_t = [0.0]
def timed(*a, **k):
    t0 = time.thread_time()
    try: return solve(*a, **k)
    finally: lm_t[0] += time.thread_time() - t0
lba.bundle_adjust_points = timed
tot, lm = [], []
for _ in range(reps):
    m = LocalMapper(rec["calibration"], params); lm_t[0] = 0.0; t = 0.0
    for kf in kfs:
        t0 = time.thread_time(); m.insert_keyframe(kf); t += time.thread_time() - t0
    tot.append(t / len(kfs) * 1e3); lm.append(lm_t[0] / len(kfs) * 1e3)
out = [a - b for a, b in zip(tot, lm)]
print("OUT", " ".join(f"{x:.2f}" for x in out), "| total", " ".join(f"{x:.2f}" for x in tot), "| solver", " ".join(f"{x:.2f}" for x in lm))
