# experiment: inflate the pose solver's sigma for weak corners (response below the frame's median)
import sys, os
import numpy as np
import canopy.frontend.map_tracking as mt
from canopy.frontend.pose import refine_pose
P = float(os.environ.get("WPOW", "0.5")); CAP = float(os.environ.get("WCAP", "3"))
def _refine(self, T_cw, X, r, feats, stereo, inliers=None, line_obs=None):
    p = self.params
    meas = np.concatenate([feats.uv[r].astype(np.float64), stereo.u_right[r, None].astype(np.float64)], axis=1)
    resp = feats.response.astype(np.float64)
    med = np.median(resp[r]) if len(r) else 1.0
    f = np.clip((max(med, 1e-12) / np.maximum(resp[r], 1e-12)) ** P, 1.0, CAP)
    if os.environ.get("WDBG"): print("W", np.quantile(f, [.1, .5, .9]), med, np.quantile(resp[r], [.1,.5,.9]), P, CAP, flush=True)
    return mt.refine_pose(T_cw, X, meas, stereo.valid[r], self._sigma(feats.octave[r]) * f, self.calib,
                       p.pose_opt_rounds, p.pose_opt_iterations, p.chi2_mono, p.chi2_stereo, inliers=inliers)
mt.MapTrackingMixin._refine = _refine
import canopy.frontend.cell_extractor as ce
_init = ce.CellExtractor.__init__
def _init2(self, params, responses=True):
    _init(self, params, True)
ce.CellExtractor.__init__ = _init2
sys.argv = [sys.argv[0]] + sys.argv[1:]
exec(open(os.path.join(os.getcwd(), "docs/results/s9_jitter/diag.py")).read())
