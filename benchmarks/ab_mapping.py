#!/usr/bin/env python
"""Local mapping of this checkout against another checkout's, on the same keyframes (issue 8: speed).

Records the keyframes (``KeyframeData``) and every Schur bundle-adjustment call of one in-process
lockstep run of this checkout (``profile_tracking.run_once``), then

1. **BA call by call**: this checkout's ``canopy/backend/stereo_ba.py`` and ``--base``'s (loaded
   by path) solve every recorded call alternately (``time.thread_time`` per call; a shared
   machine's load hits both alike) and their results are compared bit for bit;
2. **the whole mapper**: ``LocalMapper.insert_keyframe`` on the recorded keyframes, ``--reps``
   times, in two processes started together (this checkout and ``--base`` on its own
   ``PYTHONPATH``): CPU per keyframe and a checksum of the final map, which must agree.

    git archive <base-commit> | tar -x -C /tmp/base
    PYTHONPATH=$PWD python benchmarks/ab_mapping.py --base /tmp/base --reps 5
"""
from __future__ import annotations

import argparse
import hashlib
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ab_checkout import load_module  # noqa: E402  (a sibling: benchmarks/ is sys.path[0])

ROOT = Path(__file__).resolve().parents[1]
if "--replay" not in sys.argv:   # a replay runs the checkout on its PYTHONPATH (the base's for the base)
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def record(dataset: str, out: Path) -> None:
    """Keyframes and BA calls of one in-process run of this checkout, pickled to ``out``."""
    import profile_tracking
    import canopy.backend.local_ba as local_ba
    from canopy.backend import LocalMapper
    from canopy.sources import open_source

    src = open_source(dataset, None)
    frames = [src.frame(i) for i in range(len(src))]
    keyframes, calls = [], []
    insert, solve = LocalMapper.insert_keyframe, local_ba.bundle_adjust_points

    def insert_recorded(self, kf):
        keyframes.append(pickle.dumps(kf))
        return insert(self, kf)

    def solve_recorded(*args, **kwargs):   # kwargs (final_projection) are outputs: not recorded
        calls.append(args)
        return solve(*args, **kwargs)

    LocalMapper.insert_keyframe, local_ba.bundle_adjust_points = insert_recorded, solve_recorded
    try:
        profile_tracking.run_once(dataset, frames, src.calibration, [])
    finally:
        LocalMapper.insert_keyframe, local_ba.bundle_adjust_points = insert, solve
    with open(out, "wb") as f:
        pickle.dump({"dataset": dataset, "calibration": src.calibration, "keyframes": keyframes, "ba_calls": calls}, f)


def replay(recording: Path, reps: int) -> None:
    """Mapping CPU per keyframe of the checkout on ``sys.path`` (printed as one parseable line)."""
    from canopy.backend import LocalMapper
    from canopy.config import load_run_config

    with open(recording, "rb") as f:
        rec = pickle.load(f)
    params = load_run_config(rec["dataset"]).mapping
    per_kf, checksum = [], None
    for _ in range(reps):
        mapper, total = LocalMapper(rec["calibration"], params), 0.0
        updates = hashlib.sha256()   # every local map sent to tracking: ids, positions, descriptors, poses
        for blob in rec["keyframes"]:
            kf = pickle.loads(blob)
            t0 = time.thread_time()
            u = mapper.insert_keyframe(kf)
            total += time.thread_time() - t0
            for a in (u.landmark_ids, u.positions, u.descriptors, *(u.keyframe_poses[k] for k in sorted(u.keyframe_poses))):
                updates.update(np.ascontiguousarray(a).tobytes())
        per_kf.append(total / max(len(rec["keyframes"]), 1) * 1e3)
        pts = mapper.map_points()
        poses = np.array([mapper.keyframes[k].T_world_cam for k in sorted(mapper.keyframes)], float)
        ids = np.array(sorted(mapper.landmarks), np.int64)
        # bit-level: every point, keyframe pose and landmark id (a float sum can hide a changed last bit)
        desc = np.array([mapper.landmarks[i].descriptor for i in ids.tolist()], np.uint8)
        obs = np.array([(i, k, j) for i in ids.tolist() for k, j in mapper.landmarks[i].obs.items()], np.int64)
        digest = hashlib.sha256(pts.tobytes() + poses.tobytes() + ids.tobytes() + desc.tobytes()
                                + obs.tobytes()).hexdigest()[:16]
        checksum = (f"{len(pts)} points, sum {pts.sum():.9f}, sha256 {digest} (map: points, poses, ids, "
                    f"descriptors, observations), updates sha256 {updates.hexdigest()[:16]}")
    import canopy
    print("REPLAY", " ".join(f"{x:.2f}" for x in per_kf), "|", checksum, "|", Path(canopy.__file__).parents[1])


def ab_ba(base_root: Path, rec: dict, reps: int) -> str:
    rel = Path("canopy/backend/stereo_ba.py")
    mods = load_module(base_root / rel, "base_stereo_ba"), load_module(ROOT / rel, "this_stereo_ba")
    times, same = ([], []), 0
    for _ in range(reps):
        for T_cw, n_local, X, e, calib, iters in rec["ba_calls"]:
            out = []
            for m, t in zip(mods, times):
                edges = m.StereoEdges(e.pose, e.point, e.meas, e.stereo, e.sigma, e.huber)
                t0 = time.thread_time()
                out.append(m.bundle_adjust_points(T_cw, n_local, X, edges, calib, iters))
                t.append(time.thread_time() - t0)
            same += all(np.array_equal(a, b) for a, b in zip(*out))
    tb, tt = (sum(t) / len(t) * 1e3 for t in times)
    return (f"BA calls: {len(times[0])}: base {tb:.2f} ms, this {tt:.2f} ms per call (thread CPU, mean), "
            f"ratio {tt / tb:.3f}; identical results {same}/{len(times[0])}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, help="the other checkout's root")
    ap.add_argument("--dataset", default="kitti")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--recording", type=Path, help="reuse (or, if missing, write) this recording instead of a temporary one")
    ap.add_argument("--replay", type=Path, help=argparse.SUPPRESS)   # internal: one side of the mapper A/B
    a = ap.parse_args()
    if a.replay:
        replay(a.replay, a.reps)
        return 0
    if a.base is None:
        ap.error("--base is required")
    with tempfile.TemporaryDirectory() as tmp:
        path = a.recording or Path(tmp) / "recording.pkl"
        if not path.is_file():
            record(a.dataset, path)
        with open(path, "rb") as f:
            rec = pickle.load(f)
        print(f"{a.dataset}: {len(rec['keyframes'])} keyframes, {len(rec['ba_calls'])} BA calls recorded")
        print(ab_ba(a.base, rec, a.reps))
        procs = {}
        for name, root in (("base", a.base.resolve()), ("this", ROOT)):
            env = dict(os.environ, PYTHONPATH=str(root))
            procs[name] = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--replay", str(path),
                                            "--reps", str(a.reps)], cwd=root, env=env, stdout=subprocess.PIPE, text=True)
        lines = {name: next((ln for ln in p.communicate()[0].splitlines() if ln.startswith("REPLAY")), "REPLAY failed")
                 for name, p in procs.items()}
        for name, line in lines.items():
            print(f"mapper {name}: CPU ms per keyframe (reps) {line[len('REPLAY '):]}")
        med = {n: float(np.median([float(x) for x in ln.split("|")[0].split()[1:]])) for n, ln in lines.items()
               if "failed" not in ln}
        if len(med) == 2:
            same = lines["base"].split("|")[1].strip() == lines["this"].split("|")[1].strip()
            print(f"mapper: median base {med['base']:.1f} ms, this {med['this']:.1f} ms per keyframe, "
                  f"ratio {med['this'] / med['base']:.3f}; same final map: {same}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
