#!/usr/bin/env python
"""s13-haze experiment (not shipped): ORB-SLAM's TrackReferenceKeyFrame first on the frame after
(re)initialisation -- stage 1 takes the descriptor-only matches against the local map when there is
no velocity yet, instead of the window search around a zero-motion prediction (which, with the
fill-in's far points, gives RANSAC a consensus of far points that fix rotation but not translation:
frame 1 of g1-b0.06-low ends 314 mm off). Runs diag_frames.py's loop with a Tracker subclass.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s13_haze/appearance_first.py <cell dir> [--set ...]
"""
import runpy
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
import canopy.frontend as frontend  # noqa: E402
from canopy.frontend import Tracker  # noqa: E402


class AppearanceFirst(Tracker):
    def _initial_matches(self, T_pred_cw, view, feats, kp_words):
        if not self._velocity_valid and len(view.ids):
            cand = self._appearance_matches(view, feats)
            if len(cand[1]) >= 2 * self.params.min_inliers:
                return cand
        return super()._initial_matches(T_pred_cw, view, feats, kp_words)


frontend.Tracker = AppearanceFirst
sys.argv = [str(Path(__file__).with_name("diag_frames.py"))] + sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
