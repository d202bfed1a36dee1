#!/usr/bin/env python
"""s13-haze: on how many left images of a sequence the stereo fill-in's gate fires (configs/kitti.yaml
rule), with the robust sigma and texture excess ranges (non-enhanced frames; the extractor's figures).

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/fill_gate.py <dir> [<dir> ...]
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.noisy_features import tracking_extractor  # noqa: E402
from canopy.frontend.stereo_fill import fill_active  # noqa: E402
from canopy.frontend.track_health import image_noise_sigma  # noqa: E402
from canopy.sources import open_source  # noqa: E402

p = load_run_config("kitti").tracking
ex = tracking_extractor(p, responses=False)
for d in sys.argv[1:]:
    src = open_source("kitti", d)
    fire, rob, exc = 0, [], []
    for i in range(len(src)):
        img = src.frame(i).left
        ns = image_noise_sigma(img)
        f = ex.extract(img, noise_sigma=ns)
        fire += fill_active(f, p, img, ns)
        rob.append(f.robust_noise_sigma)
        exc.append(ns - f.robust_noise_sigma)
    print(f"{Path(d).name}: fires on {fire}/{len(src)}; robust sigma {min(rob):.2f}-{max(rob):.2f}, "
          f"texture excess {min(exc):.2f}-{max(exc):.2f}")
