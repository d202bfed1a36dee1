#!/usr/bin/env python
"""The flow stereo matcher (``tracking.stereo_matcher: flow``) against the descriptor matcher on the
same left keypoints, pair by pair (issue 8: speed; docs/notes/s11-speed.md).

Per stereo pair of a sequence (the dataset's tracking config, the tracker's left extractor): the
descriptor matcher (right-image ORB + ``match_stereo``) and the flow matcher (``match_stereo_flow``),
each timed as this thread's CPU (``time.thread_time``; the descriptor side includes the right ORB);
matches each finds, and on the keypoints both match the median and 90th percentile of
|disparity_flow - disparity_descriptor| and the share > 1 px. Against a reference, the clean pair's
SGBM disparity (canopy.degrade.disparity_sgbm, at the rounded keypoint, where it is valid): each
matcher's median |error| and share > 1 px, and the same for the matches only the flow finds.
Prints medians over the pairs.

    PYTHONPATH=$PWD python benchmarks/ab_stereo_flow.py --dataset kitti --every 10
    PYTHONPATH=$PWD python benchmarks/ab_stereo_flow.py --dataset kitti \\
        --path /work/cache/degraded/kitti-all-g1-b0-high-seed0 --every 10
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canopy.config import load_run_config  # noqa: E402
from canopy.degrade import disparity_sgbm  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402
from canopy.frontend.noisy_features import refinement_pair  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.frontend.stereo_flow import match_stereo_flow  # noqa: E402
from canopy.frontend.track_health import image_noise_sigma  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="kitti", help="config and source kind (kitti, euroc)")
    ap.add_argument("--path", default=None, help="sequence folder (default: the bundled one)")
    ap.add_argument("--clean-path", default=None, help="the clean sequence for the SGBM reference "
                    "(default: the bundled one)")
    ap.add_argument("--every", type=int, default=10, help="use every n-th pair")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="tracking parameter override for the flow side, e.g. flow_levels=4")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    cv2.setNumThreads(1)  # one thread: thread_time is the whole cost
    cfg = load_run_config(a.dataset)
    tp = cfg.tracking
    sets = {}
    for s in a.set:
        k, v = s.split("=", 1)
        sets[k] = type(getattr(tp, k))(v)
    tp_flow = dataclasses.replace(tp, stereo_matcher="flow", **sets)
    tp_flow.validate()
    src = open_source(a.dataset, a.path)
    clean = open_source(a.dataset, a.clean_path)
    tracker = Tracker(src.calibration, tp)
    calib = src.calibration
    rows = []
    for i in range(0, len(src), a.every):
        f = src.frame(i)
        sigma = image_noise_sigma(f.left)
        left = tracker.extractor.extract(f.left, noise_sigma=sigma)
        t0 = time.thread_time()
        right = tracker.extractor_right.extract(f.right)
        sd = match_stereo(left, right, f.left, f.right, calib, tp, sigma)
        t_desc = (time.thread_time() - t0) * 1e3
        t0 = time.thread_time()
        sf = match_stereo_flow(left, f.left, f.right, calib, tp_flow, sigma)
        t_flow = (time.thread_time() - t0) * 1e3
        both = sd.valid & sf.valid
        fc = clean.frame(i)
        ref = disparity_sgbm(fc.left, fc.right)
        x = np.clip(np.round(left.uv[:, 0]).astype(int), 0, ref.shape[1] - 1)
        y = np.clip(np.round(left.uv[:, 1]).astype(int), 0, ref.shape[0] - 1)
        d_ref = ref[y, x]
        has_ref = d_ref > 0

        def err(st):
            m = st.valid & has_ref
            return np.abs(left.uv[m, 0] - st.u_right[m] - d_ref[m])
        e_d, e_f = err(sd), err(sf)
        only = dataclasses.replace(sf, depth=np.where(sd.valid, -1.0, sf.depth).astype(np.float32))
        e_o = err(only)
        dd = np.abs((sd.u_right - sf.u_right)[both])
        rows.append({"frame": i, "n_left": len(left), "desc_ms": t_desc, "flow_ms": t_flow,
                     "n_desc": int(sd.valid.sum()), "n_flow": int(sf.valid.sum()), "n_both": int(both.sum()),
                     "med_px": float(np.median(dd)) if len(dd) else float("nan"),
                     "p90_px": float(np.percentile(dd, 90)) if len(dd) else float("nan"),
                     "gt1_pct": float(100 * np.mean(dd > 1)) if len(dd) else float("nan"),
                     "sgbm_desc_med": float(np.median(e_d)), "sgbm_desc_gt1": float(100 * np.mean(e_d > 1)),
                     "sgbm_flow_med": float(np.median(e_f)), "sgbm_flow_gt1": float(100 * np.mean(e_f > 1)),
                     "sgbm_only_med": float(np.median(e_o)), "sgbm_only_gt1": float(100 * np.mean(e_o > 1))})
    med = {k: float(np.median([r[k] for r in rows])) for k in rows[0] if k != "frame"}
    print(f"{a.dataset} {a.path or '(bundled)'}: {len(rows)} pairs, flow {sets or 'defaults'}; medians per pair")
    for k, v in med.items():
        print(f"  {k:14s} {v:9.3f}")
    if a.out:
        a.out.write_text(json.dumps({"dataset": a.dataset, "path": a.path, "sets": sets, "median": med, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
