"""auto's statistics and decision on every 10th left image of the given sequences (+ the 1/4-scale dark channel's quantiles, noise sigma)."""
import sys, glob, cv2, numpy as np
from canopy.enhance.auto import auto_statistics, auto_decide
from canopy.enhance.params import EnhanceParams
from canopy.enhance.dehaze import dark_channel
from canopy.enhance.noise import estimate_noise
p = EnhanceParams(method="auto")
for path in sys.argv[1:]:
    files = sorted(glob.glob(path + "/image_l/*.png"))
    for f in files[::10]:
        im = cv2.imread(f, cv2.IMREAD_UNCHANGED)
        d, st = auto_decide(im, p)
        small = cv2.resize(im[:im.shape[0]//4*4, :im.shape[1]//4*4], None, fx=.25, fy=.25, interpolation=cv2.INTER_AREA)
        dk = dark_channel(small, 3)
        q = np.percentile(dk, [5, 50, 95])
        print(path.split('/')[-1][:40], f.split('/')[-1], im.shape, d, {k: round(v,1) for k,v in st.items()}, "dark q5/50/95", q, "sigma", round(estimate_noise(im),2))
