"""Per-image noise statistics of the generated presets' clean sequences and grid cells (left and right,
every STEP-th frame): robust sigma (canopy.enhance.noise.estimate_noise, rows_fraction 0.5, the
refinement's / KITTI gate's estimator), mean sigma (track_health.image_noise_sigma, the fallback floor's),
their difference (texture excess). Usage: sigma_survey.py STEP MAXFRAMES DIR [DIR ...]"""
import sys
from pathlib import Path

import cv2
import numpy as np

from canopy.enhance.noise import estimate_noise
from canopy.frontend.track_health import image_noise_sigma

step, nmax = int(sys.argv[1]), int(sys.argv[2])
for d in sys.argv[3:]:
    rob, mean, exc = [], [], []
    for cam in ("cam0", "cam1"):
        files = sorted((Path(d) / "mav0" / cam / "data").glob("*.png"))[:nmax][::step]
        for f in files:
            img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
            r, m = estimate_noise(img, rows_fraction=0.5), image_noise_sigma(img)
            rob.append(r); mean.append(m); exc.append(m - r)
    q = lambda a: f"{np.min(a):5.2f}-{np.max(a):5.2f} (med {np.median(a):5.2f})"  # noqa: E731
    print(f"{Path(d).name:48s} n={len(rob):4d} robust {q(rob)}  mean {q(mean)}  excess {q(exc)}", flush=True)
