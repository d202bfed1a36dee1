"""s32: import to apply a disparity offset field in the stereo matcher: the config's constant offset plus
KAPPA * d + KV * (v - H/2) / H + KU * (u - W/2) / W px (environment variables KAPPA, KV, KU, D0 = extra constant), on every
accepted match of refine_and_accept (the descriptor matcher, the fill-in and the flow matcher)."""
import os

import numpy as np

import canopy.frontend.stereo as st
import canopy.frontend.stereo_fill as sf
import canopy.frontend.stereo_flow as sfl

KV = float(os.environ.get("KV", "0"))
KU = float(os.environ.get("KU", "0"))
D0 = float(os.environ.get("D0", "0"))
KAPPA = float(os.environ.get("KAPPA", "0"))  # a disparity scale error: + KAPPA * d (a baseline x focal error)
_orig = st.refine_and_accept


def refine_and_accept(ref_left, ref_right, left, li, *a, **k):
    li, ur, disp = _orig(ref_left, ref_right, left, li, *a, **k)
    if len(li) == 0:
        return li, ur, disp
    h, w = ref_left.shape[:2]
    uv = left.uv[li].astype(np.float64)
    extra = D0 + KAPPA * disp + KV * (uv[:, 1] - h / 2) / h + KU * (uv[:, 0] - w / 2) / w
    return li, ur - extra, disp + extra


for m in (st, sf, sfl):
    m.refine_and_accept = refine_and_accept
