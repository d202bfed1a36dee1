"""The exact transmission the degradation tool painted KITTI's haze with (stereo-sky depth of the clean pair,
β 0.06, both views), as uint8 t·255 per frame -> /tmp/kittidehaze/oracle_t.npz"""
import os, sys
from _paths import CELLS, CLEAN, HERE, ORACLE_T, ROOT  # noqa: F401 (also puts the repo on sys.path)

import numpy as np
from canopy.degrade import depth_for_haze, ray_length, transmission
from canopy.sources import open_source
clean = open_source("kitti", CLEAN)
cal = clean.calibration
tl, tr = [], []
for i in range(len(clean)):
    c = clean.frame(i)
    for v, acc in (("left", tl), ("right", tr)):
        t = transmission(ray_length(depth_for_haze(c.left, c.right, cal, 200.0, 128, 5, view=v), cal), 0.06)
        acc.append(np.clip(np.rint(t * 255), 0, 255).astype(np.uint8))
np.savez_compressed(ORACLE_T, left=np.array(tl), right=np.array(tr))
print("done", np.array(tl).shape)
