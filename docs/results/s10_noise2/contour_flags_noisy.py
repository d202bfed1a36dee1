import glob
from dataclasses import replace
import numpy as np, cv2
from canopy.config import load_run_config
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.stereo import match_stereo
from canopy.frontend.stereo_silhouette import ContourParams, SilhouetteDetector
from canopy.sources import open_source
name="day-loop"
clean = open_source("euroc", f"/work/cache/synthetic/{name}-seed0-full")
noisy = open_source("euroc", f"/work/cache/degraded/day-loop-300-g1-b0-high-seed0")
cal = clean.calibration
depth_files = sorted(glob.glob(f"/work/cache/synthetic/{name}-seed0-full/mav0/depth0/data/*.png"))
base = replace(load_run_config("synthetic").tracking, parallel_extraction=False)
det = SilhouetteDetector(ContourParams.from_tracking(base))
g = lambda im, s: cv2.GaussianBlur(im, (0, 0), s)
acc = {}
for i in range(10, 300, 20):
    fc, fn = clean.frame(i), noisy.frame(i)
    dep = cv2.imread(depth_files[i], cv2.IMREAD_UNCHANGED).astype(float) / 1000.0
    fl, fr = CellExtractor(base).extract(fn.left), CellExtractor(base).extract(fn.right)
    st = match_stereo(fl, fr, fn.left, fn.right, cal, base)
    v = st.valid; uv = fl.uv[v]; oc = fl.octave[v]
    z = dep[np.clip(np.rint(uv[:,1]).astype(int),0,479), np.clip(np.rint(uv[:,0]).astype(int),0,751)]
    e = np.abs((uv[:,0]-st.u_right[v]) - cal.bf/np.maximum(z,1e-6))
    bad = (z <= 0) | (e > 1.0)
    for tag, (L, R) in {"clean": (fc.left, fc.right), "noisy": (fn.left, fn.right),
                        "noisy-g1": (g(fn.left,1), g(fn.right,1)), "noisy-g2": (g(fn.left,2), g(fn.right,2))}.items():
        f = det(L, R, uv, oc, base.scale_factor)
        a = acc.setdefault(tag, [0,0,0,0])
        a[0] += len(f); a[1] += f.sum(); a[2] += (f & bad).sum(); a[3] += (~f & bad).sum()
for tag, (n, nf, fb, kb) in acc.items():
    print(f"{tag:9s} flagged {nf/n:.3f} of {n}; stereo error >1px (or no depth): among flagged {fb/max(nf,1):.3f}, among kept {kb/max(n-nf,1):.3f}, kept bad {kb}")
