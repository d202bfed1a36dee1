# Disparity error against the renderer's exact depth, split by the contour test's verdict
# (canopy.frontend.stereo_silhouette on the raw pair, as the tracker runs it), raw refinement vs the
# smoothed one. Usage: truth_split.py day-loop|haze-row [blur ...]
import sys, glob
from dataclasses import replace
import numpy as np, cv2
from canopy.config import load_run_config
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.features import OrbExtractor
from canopy.frontend.stereo import match_stereo
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector
from canopy.sources import open_source
name = sys.argv[1]
blurs = [float(b) for b in sys.argv[2:]] or [1.5, 2.0]
cellname = {"day-loop": "day-loop-300-g1-b0-high-seed0", "haze-row": "haze-row-346-g1-b0-high-seed0"}[name]
noisy = open_source("euroc", f"/work/cache/degraded/{cellname}")
cal = noisy.calibration
depth_files = sorted(glob.glob(f"/work/cache/synthetic/{name}-seed0-full/mav0/depth0/data/*.png"))
base = replace(load_run_config("synthetic").tracking, parallel_extraction=False)
det = SilhouetteDetector(ContourParams.from_tracking(base))
res = {}
for i in range(10, 300, 20):
    f = noisy.frame(i)
    dep = cv2.imread(depth_files[i], cv2.IMREAD_UNCHANGED).astype(float) / 1000.0
    mk = (lambda: OrbExtractor(base)) if base.extractor == "opencv" else (lambda: CellExtractor(base))
    fl, fr = mk().extract(f.left), mk().extract(f.right)
    onc = det(f.left, f.right, fl.uv, fl.octave, base.scale_factor)
    for blur in [0.0] + blurs:
        p = base if blur == 0 else replace(base, subpixel_denoise_sigma=1e-3, subpixel_denoise_blur=blur)
        st = match_stereo(fl, fr, f.left, f.right, cal, p)
        v = st.valid
        uv = fl.uv[v]
        z = dep[np.clip(np.rint(uv[:, 1]).astype(int), 0, dep.shape[0]-1), np.clip(np.rint(uv[:, 0]).astype(int), 0, dep.shape[1]-1)]
        ok = z > 0
        e = np.full(len(uv), np.nan)
        e[ok] = (uv[ok, 0] - st.u_right[v][ok]) - cal.bf / z[ok]
        c = onc[v]
        oc = fl.octave[v]
        for tag, m in (("all", np.ones(len(c), bool)), ("contour", c), ("interior", ~c)):
            res.setdefault((blur, tag), []).append((e[m & ok], z[m & ok], oc[m & ok]))
for (blur, tag), parts in sorted(res.items(), key=lambda kv: (kv[0][1], kv[0][0])):
    e = np.concatenate([p[0] for p in parts]); z = np.concatenate([p[1] for p in parts])
    c = np.clip(e, -2, 2)
    far = z > 10
    print(f"{name} {tag:8s} blur {blur:.1f}: n {len(e):5d} mean {c.mean():+.3f} med|e| {np.median(np.abs(e)):.3f} "
          f">0.5 {np.mean(np.abs(e)>0.5):.3f} >1 {np.mean(np.abs(e)>1):.3f} | far(z>10) n {far.sum()} mean {np.clip(e[far],-2,2).mean():+.3f} med|e| {np.median(np.abs(e[far])) if far.any() else float('nan'):.3f}")
