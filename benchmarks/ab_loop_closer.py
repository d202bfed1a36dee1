#!/usr/bin/env python
"""The loop closer of this checkout against another checkout's, on the same keyframes (issue 8: speed).

Input: a recording of ``benchmarks/profile_loop_closer.py --record`` (the ``PlaceKeyframe`` and
window poses of every keyframe the loop closer was given). Three comparisons:

1. **bag of words**: this checkout's ``Vocabulary.transform`` and ``--base``'s (its
   ``canopy/place/vocabulary.py`` loaded by path) on every keyframe's descriptors, alternately:
   thread CPU per keyframe and whether words and weights are identical;
2. **database scores**: this checkout's ``KeyframeDatabase`` and the base's fed the same keyframes,
   each query scored by both before the keyframe is added: CPU per query, identical scores;
3. **the worker's whole step** (``place_keyframe`` from a ``LoopKeyframe``, then
   ``LoopCloser.add_keyframe``) in two processes run one after the other, ``--alternations`` times
   (this checkout and ``--base`` each on its own ``PYTHONPATH``): CPU per keyframe and the loops closed.

    git archive <base-commit> | tar -x -C /tmp/base
    PYTHONPATH=$PWD python benchmarks/profile_loop_closer.py --record /tmp/kitti.pkl --dataset kitti
    PYTHONPATH=$PWD python benchmarks/ab_loop_closer.py --base /tmp/base --recording /tmp/kitti.pkl
"""
from __future__ import annotations

import argparse
import copy
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ab_checkout import load_module  # noqa: E402  (a sibling: benchmarks/ is sys.path[0])

ROOT = Path(__file__).resolve().parents[1]
if "--step" not in sys.argv:   # a step replay runs the checkout on its PYTHONPATH (the base's for the base)
    sys.path.insert(0, str(ROOT))


def ab_bow(base_root: Path, rec: dict, vocabulary_path: Path) -> str:
    mods = load_module(base_root / "canopy/place/vocabulary.py", "base_vocabulary"), \
        load_module(ROOT / "canopy/place/vocabulary.py", "this_vocabulary")
    vocs = [m.Vocabulary.load(vocabulary_path) for m in mods]
    times, same = ([], []), 0
    for kf, _ in rec["inputs"]:
        out = []
        for v, t in zip(vocs, times):
            t0 = time.thread_time()
            out.append(v.transform(kf.descriptors))
            t.append(time.thread_time() - t0)
        (b0, w0), (b1, w1) = out
        same += b0 == b1 and list(b0) == list(b1) and np.array_equal(w0, w1)
    p = [float(np.median(t)) * 1e3 for t in times]
    return (f"BoW transform: {len(times[0])} keyframes, p50 base {p[0]:.2f} ms, this {p[1]:.2f} ms "
            f"(ratio {p[1] / p[0]:.3f}); identical words and weights {same}/{len(times[0])}")


def ab_database(base_root: Path, rec: dict) -> str:
    mods = load_module(base_root / "canopy/loop/database.py", "base_database"), \
        load_module(ROOT / "canopy/loop/database.py", "this_database")
    dbs = [m.KeyframeDatabase() for m in mods]
    times, same = [0.0, 0.0], 0
    for kf, _ in rec["inputs"]:
        out = []
        for i, db in enumerate(dbs):
            t0 = time.thread_time()
            out.append(db.scores(kf.bow, kf.line_bow, kf.stats))
            times[i] += time.thread_time() - t0
            db.add(kf.index, kf.bow, kf.line_bow, kf.stats)
        same += out[0] == out[1] and list(out[0]) == list(out[1])
    n = len(rec["inputs"])
    return (f"database scores: {n} queries, mean base {times[0] / n * 1e3:.2f} ms, this {times[1] / n * 1e3:.2f} ms; "
            f"identical scores {same}/{n}")


def step(recording: Path, reps: int) -> None:
    """The worker's step on the checkout on ``sys.path`` (printed as one parseable line)."""
    from canopy.config import load_run_config
    from canopy.loop.closer import LoopCloser
    from canopy.loop.vocabulary import load_vocabulary
    from canopy.loop.worker import place_keyframe
    from protocol.messages import LoopKeyframe

    with open(recording, "rb") as f:
        rec = pickle.load(f)
    cfg = load_run_config(rec["dataset"])
    voc = load_vocabulary(cfg.loop.vocabulary)
    msgs = [LoopKeyframe(index=kf.index, timestamp=kf.timestamp, T_world_cam=kf.T_world_cam,
                         uv=np.asarray(kf.uv, np.float32), u_right=np.asarray(kf.u_right, np.float32),
                         depth=np.asarray(kf.depth, np.float32), octave=np.asarray(kf.octave, np.int32),
                         descriptors=kf.descriptors, landmark_ids=kf.landmark_ids, window_poses=wp,
                         landmark_positions=kf.landmark_positions) for kf, wp in rec["inputs"]]
    per, closed = [], []
    for _ in range(reps):
        closer = LoopCloser(rec["calibration"], cfg.loop, voc)
        for m in copy.deepcopy(msgs):
            t0 = time.thread_time()
            kf = place_keyframe(m, voc)
            closure = closer.add_keyframe(kf, dict(m.window_poses))
            per.append(time.thread_time() - t0)
            if closure is not None:
                closed.append((int(m.index), int(closure.constraint.candidate), int(closure.constraint.n_inliers)))
            closer.ba_pending = False   # the full BA runs in its own process in the actor; not timed here
    a = np.asarray(per) * 1e3
    print(f"STEP {np.median(a):.2f} {a.mean():.2f} | loops {closed[:len(closed) // max(reps, 1)]}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, help="the other checkout's root")
    ap.add_argument("--recording", type=Path, required=True, help="profile_loop_closer.py --record output")
    ap.add_argument("--reps", type=int, default=3, help="replays per step process")
    ap.add_argument("--alternations", type=int, default=2)
    ap.add_argument("--step", action="store_true", help=argparse.SUPPRESS)   # internal: one side of the step A/B
    a = ap.parse_args()
    if a.step:
        step(a.recording, a.reps)
        return 0
    if a.base is None:
        ap.error("--base is required")
    from canopy.config import load_run_config
    from canopy.loop.vocabulary import default_vocabulary_path

    with open(a.recording, "rb") as f:
        rec = pickle.load(f)
    vocabulary = load_run_config(rec["dataset"]).loop.vocabulary or default_vocabulary_path()
    print(ab_bow(a.base, rec, Path(vocabulary)))
    print(ab_database(a.base, rec))
    for _ in range(a.alternations):
        for name, root in (("base", a.base.resolve()), ("this", ROOT)):
            env = dict(os.environ, PYTHONPATH=str(root))
            out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--step", "--recording",
                                  str(a.recording.resolve()), "--reps", str(a.reps)], cwd=root, env=env,
                                 capture_output=True, text=True).stdout
            line = next((ln for ln in out.splitlines() if ln.startswith("STEP")), "STEP failed")
            p50_mean, loops = (line[5:].split("|") + [""])[:2]
            print(f"worker step {name}: CPU ms per keyframe p50 / mean {p50_mean.strip()} |{loops}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
