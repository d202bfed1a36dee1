import sys
from dataclasses import replace
import numpy as np, cv2
sys.path.insert(0,'.')
from tests.test_stereo_denoise import _noisy, KITTI
from canopy.config import load_run_config
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.stereo import match_stereo
from canopy.sources import open_source
src = open_source("kitti", KITTI)
base = replace(load_run_config("kitti").tracking, parallel_extraction=False)
for blur in [1.0,1.5,0.0]:
    on = replace(base, subpixel_denoise_sigma=4.0, subpixel_denoise_blur=blur)
    on_clean = replace(base, subpixel_denoise_sigma=0.001, subpixel_denoise_blur=blur)
    R={k:[] for k in ['raw-ref','dn-ref','dn-refdn','refdn-ref']}
    for i in (5,20,35):
        f = src.frame(i)
        nl, nr = _noisy(f.left, 2 * i), _noisy(f.right, 2 * i + 1)
        fl, fr = CellExtractor(base).extract(nl), CellExtractor(base).extract(nr)
        raw = match_stereo(fl, fr, nl, nr, src.calibration, base)
        dn = match_stereo(fl, fr, nl, nr, src.calibration, on)
        ref = match_stereo(fl, fr, f.left, f.right, src.calibration, base)
        refdn = match_stereo(fl, fr, f.left, f.right, src.calibration, on_clean)
        b = raw.valid & dn.valid & ref.valid & refdn.valid
        d = lambda a: fl.uv[b,0]-a.u_right[b]
        R['raw-ref'].append(d(raw)-d(ref)); R['dn-ref'].append(d(dn)-d(ref)); R['dn-refdn'].append(d(dn)-d(refdn)); R['refdn-ref'].append(d(refdn)-d(ref))
    print('blur',blur, 'n', sum(len(x) for x in R['raw-ref']))
    for k,v in R.items():
        v=np.concatenate(v); print(f"  {k:10s} mean {v.mean():+.3f} median {np.median(v):+.3f} med|.| {np.median(np.abs(v)):.3f} rms-clip {np.sqrt(np.mean(np.clip(v,-2,2)**2)):.3f} >0.5px {np.mean(np.abs(v)>0.5):.3f}")
