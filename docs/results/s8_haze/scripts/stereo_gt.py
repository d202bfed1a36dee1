"""Stereo disparities of the tracker's own matches vs the exact rendered depth (dark-rows)."""
import glob, cv2, numpy as np
from dataclasses import replace
from canopy.config import load_run_config
from canopy.sources import open_source
from canopy.enhance.factory import make_enhancer
from canopy.frontend.cell_extractor import make_extractor
from canopy.frontend.stereo import match_stereo
from benchmarks.bench_enhance_diagnose import enhance_pair, actor_fast
cfg = load_run_config("synthetic")
import sys; src = open_source("euroc", sys.argv[1] if len(sys.argv) > 1 else "/work/cache/degraded/dark-rows-150-g1-b0.06-high-seed0", max_frames=150)
cl = open_source("euroc", "/work/cache/synthetic/dark-rows-seed0-full", max_frames=150)
depths = sorted(glob.glob("/work/cache/synthetic/dark-rows-seed0-full/mav0/depth0/data/*.png"))
c = src.calibration
for meth, extr, norm in [("auto", "opencv", "centre"), ("none", "opencv", "centre")]:
    tp = replace(cfg.tracking, extractor=extr, subpixel_normalise=norm)
    enh = replace(cfg.enhancement, method=meth); E = make_enhancer(enh)
    for name, s in (("hazy", src), ("clean", cl)):
        if name == "clean" and meth == "none": continue
        res = []
        for i in [0, 10, 20, 40, 80]:
            f = s.frame(i)
            le, re, info = enhance_pair(E, f.left, f.right)
            kw = actor_fast(enh, info, le, tp.n_features)
            L = make_extractor(tp).extract(le, kw.get("fast_threshold"), kw.get("fast_fallback"), kw.get("fast_min_keypoints", 0))
            R = make_extractor(tp).extract(re, kw.get("fast_threshold"), kw.get("fast_fallback"), kw.get("fast_min_keypoints", 0))
            st = match_stereo(L, R, le, re, c, tp)
            Z = cv2.imread(depths[i], cv2.IMREAD_UNCHANGED).astype(float) / 1000.0
            uv = L.uv[st.valid]; d = uv[:, 0] - st.u_right[st.valid]
            z = Z[np.clip(np.rint(uv[:, 1]).astype(int), 0, c.height - 1), np.clip(np.rint(uv[:, 0]).astype(int), 0, c.width - 1)]
            ok = z > 0
            err = d[ok] - c.fx * c.baseline / z[ok]
            res.append((len(L), int(st.valid.sum()), np.mean(np.abs(err) > 1), np.median(np.abs(err))))
        r = np.array(res)
        print(meth, extr, norm, name, "kp %.0f stereo %.0f bad>1px %.2f med|err| %.2f" % tuple(r.mean(0)), flush=True)
