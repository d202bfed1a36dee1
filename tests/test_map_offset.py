"""The rig's disparity offset from a whole map's bundle adjustment (canopy.backend.map_offset), on a
generated map with exact ground truth: a KITTI-like rig driving forward past points 5-80 m away."""
from types import SimpleNamespace

import numpy as np
import pytest

from canopy.backend.map_offset import fit_minimum, map_offset_profile, map_problem
from canopy.backend.params import MappingParams
from shared.types import StereoCalibration

CALIB = StereoCalibration(fx=718.0, fy=718.0, cx=607.0, cy=185.0, baseline=0.54, width=1226, height=370)
MP = MappingParams()


def _pose(x: float, z: float, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = [x, 0.0, z]
    return T


def generated_map(offset_px: float, noise_px: float = 0.3, n_keyframes: int = 12, seed: int = 0,
                  step_m: float = 1.0):
    """Keyframes and landmarks as a mapper holds them; every stereo measurement's disparity is
    ``offset_px`` short of the truth (d_measured = d_true - offset), as on a rig with that offset."""
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(-25, 25, 900), rng.uniform(-3, 2, 900), rng.uniform(5, 90, 900)])
    keyframes, obs = {}, {j: {} for j in range(len(P))}
    for k in range(n_keyframes):
        T_wc = _pose(0.1 * np.sin(k), step_m * k, 0.01 * k)
        Pc = (P - T_wc[:3, 3]) @ T_wc[:3, :3]
        z = Pc[:, 2]
        u = CALIB.fx * Pc[:, 0] / np.maximum(z, 1e-9) + CALIB.cx
        v = CALIB.fy * Pc[:, 1] / np.maximum(z, 1e-9) + CALIB.cy
        seen = np.flatnonzero((z > 2) & (u > 0) & (u < CALIB.width) & (v > 0) & (v < CALIB.height))
        n = len(seen)
        uv = np.column_stack([u[seen], v[seen]]) + rng.normal(0, noise_px, (n, 2))
        ur = uv[:, 0] - (CALIB.bf / z[seen] - offset_px) + rng.normal(0, noise_px, n)
        keyframes[k] = SimpleNamespace(T_world_cam=T_wc, uv=uv, u_right=ur, octave=np.zeros(n, np.int64))
        for i, j in enumerate(seen.tolist()):
            obs[j][k] = i
    # the map's points start near the truth, as a tracked map's do
    landmarks = {j: SimpleNamespace(obs=o, position=P[j] + rng.normal(0, 0.05, 3)) for j, o in obs.items() if len(o) >= 2}
    return keyframes, landmarks


def _estimate(keyframes, landmarks):
    prob = map_problem(keyframes, landmarks, MP.pixel_sigma, 1.2, MP.huber_stereo, MP.huber_mono)
    return map_offset_profile(prob, CALIB, MP.chi2_stereo, MP.chi2_mono)


@pytest.mark.parametrize("offset", [0.0, 0.15, -0.25])
def test_map_offset_recovers_the_rig_offset(offset):
    prof = _estimate(*generated_map(offset))
    assert abs(prof.offset_px - offset) < 0.03, (prof.offset_px, prof.costs)
    assert 0 < prof.se_px < 0.03
    # the profile is a valley: the cost rises on both sides of the minimum
    i = int(np.argmin(prof.costs))
    assert prof.costs[0] > prof.costs[i] < prof.costs[-1]


def test_map_offset_without_motion_is_refused():
    keyframes, landmarks = generated_map(0.1, n_keyframes=2)
    with pytest.raises(ValueError, match="2 keyframes"):
        _estimate(keyframes, landmarks)


def test_fit_minimum_of_a_parabola_and_at_the_grid_edge():
    d = np.arange(-0.5, 0.51, 0.1)
    x0, se = fit_minimum(d, 3.0 * (d - 0.07) ** 2 + 5.0, n_residuals=1000)
    assert x0 == pytest.approx(0.07, abs=1e-9) and np.isfinite(se)
    x0, se = fit_minimum(d, d, n_residuals=1000)       # still falling at the edge: no minimum inside
    assert x0 == pytest.approx(-0.5) and se == float("inf")


def test_shipped_kitti_offset_is_what_the_map_measures():
    """The KITTI config's offset for the cells extractor is the map calibration's fixed point on the bundled
    KITTI 06 frames: a run at the shipped offset measures it again within two standard errors. A front-end
    change that moves where keypoints land fails here, and the offset is to be measured again
    (``benchmarks/calibrate_disparity_offset.py --dataset kitti --method map``)."""
    from benchmarks.calibrate_disparity_offset import map_estimate
    from canopy.config import load_run_config
    from canopy.sources import open_source

    cfg = load_run_config("kitti")
    src = open_source("kitti", None)
    out = map_estimate(src, cfg, len(src), passes=1)
    assert out["run_offset_px"] == cfg.tracking.disparity_offset_cells_px
    assert 0 < out["se_px"] < 0.03
    assert abs(out["offset_px"] - out["run_offset_px"]) < 2 * out["se_px"], out
