"""Local-mapping actor's work per keyframe outside ``insert_keyframe`` (thread CPU), on a recording of
benchmarks/ab_mapping.py: decoding the KeyframeData, encoding the update for tracking, building and
encoding the loop closer's keyframe, a map snapshot (built and encoded; the actor publishes at most
one per snapshot_period_s, 0.5 s).

    PYTHONPATH=$PWD python docs/results/s17_mapcost/actor_extras.py /tmp/rec_kitti.pkl
"""
import pickle, sys, time
from collections import defaultdict

import numpy as np

from actors.local_mapping import LocalMappingActor
from canopy.backend import LocalMapper
from canopy.config import load_run_config
from canopy.loop.mapping_hooks import loop_keyframe_message
from protocol.codec import decode, encode

rec = pickle.load(open(sys.argv[1], "rb"))
params = load_run_config(rec["dataset"]).mapping
reps = int(sys.argv[2]) if len(sys.argv) > 2 else 2
acc = defaultdict(float)
sizes = defaultdict(int)
for _ in range(reps):
    mapper = LocalMapper(rec["calibration"], params)
    actor = LocalMappingActor.__new__(LocalMappingActor)
    actor.mapper = actor_mapper = mapper
    for blob in rec["keyframes"]:
        kf = pickle.loads(blob)
        wire = encode(kf)
        t0 = time.thread_time(); kf = decode(wire); acc["decode KeyframeData"] += time.thread_time() - t0
        t0 = time.thread_time(); u = mapper.insert_keyframe(kf); acc["insert_keyframe"] += time.thread_time() - t0
        t0 = time.thread_time(); b = encode(u); acc["encode LocalMapUpdate"] += time.thread_time() - t0
        sizes["update bytes"] += len(b)
        t0 = time.thread_time(); lk = loop_keyframe_message(kf, mapper, u); acc["loop keyframe: build"] += time.thread_time() - t0
        t0 = time.thread_time(); b = encode(lk); acc["loop keyframe: encode"] += time.thread_time() - t0
        t0 = time.thread_time(); snap = LocalMappingActor._snapshot(actor, final=False); acc["snapshot: build"] += time.thread_time() - t0
        t0 = time.thread_time(); b = encode(snap); acc["snapshot: encode"] += time.thread_time() - t0
        sizes["snapshot bytes"] += len(b)
n = len(rec["keyframes"]) * reps
print(f"{rec['dataset']}: thread CPU ms per keyframe ({len(rec['keyframes'])} keyframes x {reps})")
for k, v in acc.items():
    print(f"  {k:28s} {v / n * 1e3:7.2f}")
for k, v in sizes.items():
    print(f"  {k:28s} {v / n / 1e3:7.1f} kB")
