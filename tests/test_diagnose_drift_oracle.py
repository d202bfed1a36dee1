"""The exact-depth oracle of benchmarks/diagnose_drift.py: which stereo points count as wrong."""
import importlib.util
from pathlib import Path

import numpy as np

_spec = importlib.util.spec_from_file_location(
    "diagnose_drift", Path(__file__).resolve().parents[1] / "benchmarks" / "diagnose_drift.py")
dd = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(dd)


def test_wrong_depth_flags_points_off_the_exact_depth_and_on_sky():
    depth = np.full((10, 20), 4.0, np.float32)
    depth[:, 10:] = 8.0          # a depth step at column 10
    depth[0, :] = 0.0            # top row: sky
    uv = np.array([[3.0, 5.0],   # on the 4 m surface, stereo 4.2 m: 5 % off
                   [3.0, 5.0],   # same pixel, stereo 5 m: 25 % off
                   [12.4, 5.2],  # rounds to the 8 m side, stereo 7.5 m: 6 % off
                   [9.6, 5.0],   # rounds to column 10 (8 m), stereo 4 m: the foreground's depth
                   [5.0, 0.3]])  # sky
    stereo = np.array([4.2, 5.0, 7.5, 4.0, 3.0])
    got = dd.wrong_depth(depth, uv, stereo, tol=0.10)
    assert got.tolist() == [False, True, False, True, True]
    # at 30 % the 25 % point passes; the foreground depth on the background pixel (50 %) does not
    assert dd.wrong_depth(depth, uv, stereo, tol=0.30).tolist() == [False, False, False, True, True]
