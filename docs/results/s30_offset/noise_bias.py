"""s30: does sensor noise move the sub-pixel disparities? The clean KITTI frames' keypoints (cells extractor,
both images) matched on the clean pair and, with the same keypoints, on a degraded copy of the same frames
(the grid's cell: same content plus noise); the disparity difference per keypoint, noisy - clean.

    python docs/results/s30_offset/noise_bias.py /work/cache/degraded/kitti-all-g1-b0-high-seed0 [...]
"""
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.cell_extractor import make_extractor  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.frontend.track_health import image_noise_sigma  # noqa: E402
from canopy.sources import open_source  # noqa: E402

tp = load_run_config("kitti").tracking
clean = open_source("kitti", None)
for cell in sys.argv[1:]:
    noisy = open_source("kitti", cell)
    diffs, dcs = [], []
    for i in range(0, len(clean), 2):
        fc, fn = clean.frame(i), noisy.frame(i)
        ex_l, ex_r = make_extractor(tp), make_extractor(tp)
        L, R = ex_l.extract(fc.left), ex_r.extract(fc.right)
        sc = match_stereo(L, R, fc.left, fc.right, clean.calibration, tp)
        sn = match_stereo(L, R, fn.left, fn.right, clean.calibration, tp, noise_sigma=image_noise_sigma(fn.left))
        ok = sc.valid & sn.valid
        diffs.append((L.uv[ok, 0] - sn.u_right[ok]) - (L.uv[ok, 0] - sc.u_right[ok]))
        dcs.append(L.uv[ok, 0] - sc.u_right[ok])
    d, dc = np.concatenate(diffs), np.concatenate(dcs)
    keep = np.abs(d) < 1.0
    print(f"{Path(cell).name}: {keep.sum()} keypoints, noisy - clean disparity mean {d[keep].mean():+.4f} px "
          f"(se {d[keep].std() / np.sqrt(keep.sum()):.4f}), median {np.median(d[keep]):+.4f}; "
          + ", ".join(f"d {lo}-{hi} px: {np.mean(d[keep & (dc >= lo) & (dc < hi)]):+.3f}" for lo, hi in ((0, 5), (5, 15), (15, 200))))
