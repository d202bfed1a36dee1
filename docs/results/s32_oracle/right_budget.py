"""s32: import to give the right image's extractor RIGHT_FACTOR x the corner budget (environment, default 2): its
keypoints only offer stereo candidates to the left ones, and noise takes the road's right corners first (§7)."""
import os
from dataclasses import replace

from canopy.frontend import Tracker
from canopy.frontend.noisy_features import tracking_extractor

FACTOR = float(os.environ.get("RIGHT_FACTOR", "2"))
_orig = Tracker.__init__


def __init__(self, *a, **k):
    _orig(self, *a, **k)
    p = replace(self.params, n_features=int(round(FACTOR * self.params.n_features)))
    self.extractor_right = tracking_extractor(p, responses=False)


Tracker.__init__ = __init__
