"""A final bundle adjustment of the whole map at the end of a run (``mapping.final_ba``, off by default).

Local BA only ever moves the last ``window_size`` keyframes; what it leaves is the online estimate. Once the
sequence has ended nothing is online any more, and the whole map can be adjusted together, as ORB-SLAM does
after a loop (its global BA) and as offline structure from motion does at the end: every keyframe but the
first and every landmark free, the same residuals, Huber kernels and outlier passes as local BA
(``canopy.backend.stereo_ba``, ``map_offset.map_problem``). The trajectory the run writes follows the adjusted
keyframes (each frame is written relative to its reference keyframe).

Measured (docs/notes/s30-offset.md): the noisy sensor's KITTI cells, whose online path comes out 0.2 % long at
the map-calibrated disparity offset, gain most. The presets' attitude priors (``mapping.attitude_prior``) hold
the keyframes' pitch and roll as in local BA; line landmarks are not part of this adjustment.
"""
from __future__ import annotations

import numpy as np

from canopy.backend.map_offset import map_problem
from canopy.backend.stereo_ba import bundle_adjust_points, edge_chi2
from canopy.frontend.geometry import se3_inv

FINAL_BA_ITERATIONS = 20


def final_bundle_adjust(mapper, iterations: int = FINAL_BA_ITERATIONS) -> dict:
    """Adjust every keyframe pose (the first held) and landmark of ``mapper`` (a stereo ``LocalMapper``) in
    place; returns what it did. A map of fewer than 3 keyframes is left as it is."""
    p = mapper.params
    kfs = mapper.keyframes
    if len(kfs) < 3 or not mapper.landmarks:
        return {"keyframes": len(kfs), "adjusted": False}
    scale = float(mapper.scale_factor)
    prob = map_problem(kfs, mapper.landmarks, p.pixel_sigma, scale, p.huber_stereo, p.huber_mono)
    thr = np.where(prob.edges.stereo, p.chi2_stereo, p.chi2_mono)
    attitude = _attitude_priors(mapper, prob.keyframe_ids[:prob.n_free])
    active = np.ones(len(prob.edges.pose), bool)
    T, X = prob.T_cw, prob.X
    for _ in range(p.ba_passes):
        T, X, _ = bundle_adjust_points(T, prob.n_free, X, prob.edges.take(active), mapper.calib, iterations,
                                       relative_tol=p.ba_relative_tol, attitude=attitude)
        over = edge_chi2(T, X, prob.edges, mapper.calib, p.min_depth) > thr
        if not (active & over).any():
            break
        active &= ~over
    for i, k in enumerate(prob.keyframe_ids[:prob.n_free]):   # the first keyframe (last row) stays
        kfs[k].T_world_cam = se3_inv(T[i])
    for lid, x in zip(prob.landmark_ids, X):
        mapper.landmarks[lid].position = x
    return {"keyframes": len(prob.keyframe_ids), "landmarks": len(prob.landmark_ids), "adjusted": True,
            "outlier_edges": int((~active).sum()), "edges": int(len(active))}


def _attitude_priors(mapper, free: list[int]):
    """The pitch and roll priors of the free keyframes (``mapping.attitude_prior``), as local BA has them;
    None when off or none measured. Without them the whole map's BA lets the presets' measured ups drift
    back (day-loop 15 % + haze, seed 0: 13.6 -> 29.3 mm; with them 13.6). One up_world per problem, as in
    local BA: the keyframes of the latest measured keyframe's segment carry their terms (a restart's segment
    has its own reference and shares no landmark with the others)."""
    store = getattr(mapper, "attitude", None)
    if store is None or not getattr(mapper.params, "attitude_prior", False):
        return None
    measured = [k for k in free if k in store.segment_of]
    if not measured:
        return None
    segment = store.segment_of[max(measured)]
    # -1 is no keyframe index: a keyframe of another segment keeps its row without a term
    return store.priors([k if store.segment_of.get(k) == segment else -1 for k in free])


def finish_map(mapper) -> dict | None:
    """What every runner does once the sequence has ended (the actors' local mapping, ``pipeline.run_sequential``,
    the grid's in-process loop): the final bundle adjustment when ``mapping.final_ba`` is on; None when off."""
    if not getattr(mapper.params, "final_ba", False):
        return None
    return final_bundle_adjust(mapper)
