# u_right error against the renderer's exact depth, generated day-loop / haze-row, clean and noisy pair
import sys, glob
from dataclasses import replace
import numpy as np, cv2
from canopy.config import load_run_config
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.features import OrbExtractor
from canopy.frontend.stereo import match_stereo
from canopy.sources import open_source
name = sys.argv[1]
clean = open_source("euroc", f"/work/cache/synthetic/{name}-seed0-full")
cellname = {"day-loop": "day-loop-300-g1-b0-high-seed0", "haze-row": "haze-row-346-g1-b0-high-seed0"}[name]
noisy = open_source("euroc", f"/work/cache/degraded/{cellname}")
depth_files = sorted(glob.glob(f"/work/cache/synthetic/{name}-seed0-full/mav0/depth0/data/*.png"))
base = replace(load_run_config("synthetic").tracking, parallel_extraction=False)
cal = clean.calibration
res = {}
for i in range(20, 300, 40):
    fc, fn = clean.frame(i), noisy.frame(i)
    dep = cv2.imread(depth_files[i], cv2.IMREAD_UNCHANGED).astype(float) / 1000.0
    for tag, f in (("clean", fc), ("noisy", fn)):
        E = OrbExtractor(base) if base.extractor == "opencv" else CellExtractor(base)
        E2 = OrbExtractor(base) if base.extractor == "opencv" else CellExtractor(base)
        fl, fr = E.extract(f.left), E2.extract(f.right)
        for blur in (0, 1.0, 1.5, 2.0, 3.0):
            p = base if blur == 0 else replace(base, subpixel_denoise_sigma=1e-3, subpixel_denoise_blur=blur)
            st = match_stereo(fl, fr, f.left, f.right, cal, p)
            v = st.valid
            uv = fl.uv[v]
            z = dep[np.clip(np.rint(uv[:, 1]).astype(int), 0, dep.shape[0]-1), np.clip(np.rint(uv[:, 0]).astype(int), 0, dep.shape[1]-1)]
            ok = z > 0
            d_true = cal.bf / z[ok]
            d_est = (uv[:, 0] - st.u_right[v])[ok]
            res.setdefault((tag, blur), []).append(d_est - d_true)
for k, v in sorted(res.items()):
    v = np.concatenate(v); c = np.clip(v, -2, 2)
    print(f"{name} {k[0]:5s} blur {k[1]:.1f}: n {len(v)} mean {c.mean():+.3f} med|e| {np.median(np.abs(v)):.3f} >0.5px {np.mean(np.abs(v)>0.5):.3f} >1px {np.mean(np.abs(v)>1):.3f}")
