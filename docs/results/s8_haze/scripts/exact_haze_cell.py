"""The dark-rows g1-b0.06-high cell with the haze from the renderer's exact depth instead of SGBM
on the dark clean pair (experiment; same DegradeParams, same noise seed). Left: depth0; right: the
left depth forward-warped by its disparity (z-buffer: nearest wins), occlusion holes filled with the
farther neighbour on the row; sky (0) -> max_depth, as the tool gives pixels without disparity."""
import glob, sys
import cv2, numpy as np
sys.path.insert(0, "/work/wt/s8-haze2")
import tools.degrade_sequence as ds
from canopy.degrade import DegradeParams, ray_length

CLEAN = "/work/cache/synthetic/dark-rows-seed0-full"
depths = sorted(glob.glob(CLEAN + "/mav0/depth0/data/*.png"))
p = DegradeParams(mode="haze+noise", gain=1.0, full_well=1000.0, read_noise=10.0, gamma=1.0, beta=0.06,
                  airlight=220.0, max_depth=200.0, num_disparities=128, block_size=5, seed=0)
state = {"i": 0}


def right_depth(zl, calib):
    h, w = zl.shape
    d = calib.fx * calib.baseline / zl
    ur = np.rint(np.arange(w)[None, :] - d).astype(int)
    zr = np.full((h, w), np.inf)
    rows = np.repeat(np.arange(h), w)
    ok = (ur >= 0) & (ur < w)
    np.minimum.at(zr, (rows[ok.ravel()], ur[ok]), zl[ok])
    # holes (occlusions): the farther of the nearest valid neighbours on the row
    for _ in range(2):
        holes = ~np.isfinite(zr)
        if not holes.any():
            break
        left = zr.copy(); right = zr.copy()
        for x in range(1, w):
            m = ~np.isfinite(left[:, x]); left[m, x] = left[m, x - 1]
        for x in range(w - 2, -1, -1):
            m = ~np.isfinite(right[:, x]); right[m, x] = right[m, x + 1]
        cand = np.where(np.isfinite(left) & np.isfinite(right), np.maximum(left, right), np.fmin(left, right))
        zr[holes] = cand[holes]
    zr[~np.isfinite(zr)] = 200.0
    return zr


def exact_rays(left, right, calib, params):
    z = cv2.imread(depths[state["i"]], cv2.IMREAD_UNCHANGED).astype(np.float64) / 1000.0
    state["i"] += 1
    z[z <= 0] = params.max_depth
    return [ray_length(z, calib), ray_length(right_depth(z, calib), calib)]


ds._ray_maps = exact_rays
ds.degrade_sequence("euroc", sys.argv[1], p, path=CLEAN, max_frames=150, force=True)
print("wrote", sys.argv[1], state["i"], "frames")
