"""Confirmation of cross-keyframe triangulated landmarks before tracking uses them (issues 8, 9).

``mapping.triangulate_new_points`` (canopy.backend.triangulation) makes landmarks seen by two
keyframes. docs/notes/s14-triangulate.md measured that what hurts is tracking matching them
before they are trustworthy (kept for local BA only, clean KITTI 0.0421 -> 0.0357 m). ORB-SLAM
(Mur-Artal & Tardos 2017, LocalMapping) trusts a recent point only once it has passed
MapPointCulling (observed by >= 3 keyframes for a stereo map within the next 2 keyframes), and it
adds those observations in the mapper itself: LocalMapping::SearchInNeighbors projects the new
keyframe's points into its covisible keyframes and the neighbours' points into the new keyframe
(ORBmatcher::Fuse), so a point gains observations whether or not tracking ever matched it.

Here:
* ``fuse_matches``: ORBmatcher::Fuse's search of one keyframe for projected landmarks (in front,
  in the image, viewing angle < 60 deg from the creating keyframe's ray, nearest keypoint within
  the 2-DoF chi-square radius x its octave scale, Hamming <= TH_LOW);
* ``fuse_into``: applies the matches to the map (a free keypoint becomes an observation; a
  keypoint that already has a landmark means the triangulated point duplicates it: its
  observations move to that landmark and it is removed, ORB-SLAM's MapPoint::Replace);
* ``pending_ids`` / ``confirmed_mask``: a triangulated landmark (id >= triangulate_id_base) is
  confirmed once ``triangulate_min_observations`` keyframes observe it; until then the update
  for tracking leaves it out (``withhold_unconfirmed``) and ``hidden_from_ba`` can keep it out
  of local BA too. Unconfirmed landmarks are culled by the mapper's existing rule (fewer than
  triangulate_min_observations keyframes at cull_age_keyframes).
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from canopy.frontend.geometry import project_stereo, se3_inv
from canopy.frontend.matching import as_words, band_pairs, best_two, hamming_pairs, unique_by_reference

_COS_MAX_VIEW = 0.5   # ORBmatcher::Fuse: a viewing angle over 60 deg from the point's normal is skipped


def pending_ids(landmarks, base: int, min_obs: int, segment: int) -> np.ndarray:
    """Triangulated landmarks (id >= ``base``) of map segment ``segment`` seen by fewer than
    ``min_obs`` keyframes: the ones still waiting for confirmation."""
    return np.array(sorted(lid for lid, lm in landmarks.items()
                           if lid >= base and lm.segment == segment and len(lm.obs) < min_obs), np.int64)


def confirmed_mask(ids: np.ndarray, landmarks, base: int, min_obs: int) -> np.ndarray:
    """True for the ids tracking may use: every stereo landmark, and the triangulated ones seen
    by at least ``min_obs`` keyframes."""
    ids = np.asarray(ids, np.int64)
    ok = ids < base
    tri = np.flatnonzero(~ok)
    if len(tri):
        ok[tri] = [len(landmarks[i].obs) >= min_obs for i in ids[tri].tolist()]
    return ok


def withhold_unconfirmed(update, landmarks, base: int, min_obs: int):
    """The local-map update without the unconfirmed triangulated landmarks (in place)."""
    keep = confirmed_mask(update.landmark_ids, landmarks, base, min_obs)
    if not keep.all():
        update.landmark_ids = update.landmark_ids[keep]
        update.positions = update.positions[keep]
        update.descriptors = update.descriptors[keep]
    return update


def fuse_matches(rec, pos: np.ndarray, desc: np.ndarray, ref_centres: np.ndarray, calib, scale: float,
                 chi2: float, pixel_sigma: float, max_hamming: int) -> tuple[np.ndarray, np.ndarray]:
    """ORBmatcher::Fuse's search of keyframe ``rec`` (``T_world_cam``, ``uv``, ``octave``,
    ``descriptors``) for the points ``pos`` (K,3 world) with descriptors ``desc`` (K,32): each
    point in front of the camera, inside the image and seen within 60 deg of the ray from
    ``ref_centres`` (K,3: the creating keyframe's centre, the point's viewing direction) is
    matched to the keypoint of least Hamming distance (<= ``max_hamming``) within
    sqrt(chi2) x pixel_sigma x scale^octave px of its projection (the reprojection test
    e^2 < chi2 sigma^2 of Fuse; no ratio test, as Fuse); each keypoint keeps its closest point.
    Returns (point indices, keypoint rows)."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
    pos = np.asarray(pos, np.float64).reshape(-1, 3)
    if len(pos) == 0 or len(rec.uv) == 0:
        return empty
    proj, Pc = project_stereo(se3_inv(rec.T_world_cam), pos, calib)
    ray_new = pos - rec.T_world_cam[:3, 3]
    ray_ref = pos - np.asarray(ref_centres, np.float64).reshape(-1, 3)
    cos = (ray_new * ray_ref).sum(1) / np.maximum(np.linalg.norm(ray_new, axis=1) * np.linalg.norm(ray_ref, axis=1),
                                                  1e-30)
    ok = ((Pc[:, 2] > 0) & (proj[:, 0] >= 0) & (proj[:, 0] < calib.width) & (proj[:, 1] >= 0)
          & (proj[:, 1] < calib.height) & (cos >= _COS_MAX_VIEW))
    if not ok.any():
        return empty
    # candidates: the keyframe's keypoints sorted by u, each projection's band of u within the
    # widest window (a few hundred points against ~2000 keypoints: cheaper than a cell grid per
    # call), then the circle of the keypoint's own octave, as ORB-SLAM scales the window
    sel = np.flatnonzero(ok)
    uv = np.asarray(rec.uv, np.float64)
    rad = np.sqrt(chi2) * pixel_sigma * float(scale) ** np.asarray(rec.octave, np.float64)
    order = np.argsort(uv[:, 0], kind="stable")
    rmax = float(rad.max())
    qi, rj = band_pairs(proj[sel, 0] - rmax, proj[sel, 0] + rmax, uv[order, 0])
    qi, rj = sel[qi], order[rj]
    d2 = ((proj[qi, :2] - uv[rj]) ** 2).sum(1)
    inside = d2 <= rad[rj] ** 2
    qi, rj = qi[inside], rj[inside]
    if len(qi) == 0:
        return empty
    dist = hamming_pairs(as_words(np.asarray(desc, np.uint8)), as_words(rec.descriptors), qi, rj)
    best, best_d, second_d = best_two(qi, rj, dist, len(pos))
    # no ratio test (Fuse keeps the best in the window), but a tie of two keypoints is ambiguous
    q = np.flatnonzero((best >= 0) & (best_d <= max_hamming) & (best_d < second_d))
    if len(q) == 0:
        return empty
    keep = unique_by_reference(q, best[q], best_d[q])   # each keypoint for its closest point
    return q[keep].astype(np.int64), best[q[keep]].astype(np.int64)


def fuse_into(mapper, rec, ids: np.ndarray, scale: float) -> tuple[int, int]:
    """Search keyframe ``rec`` for the landmarks ``ids`` (not yet observed by it) and apply the
    matches to ``mapper``'s stores: a match to a free keypoint adds rec's observation; a match
    to a keypoint that has a landmark already merges the (triangulated) point into that one.
    Returns (observations added, landmarks merged)."""
    p = mapper.params
    ids = np.asarray([i for i in np.asarray(ids, np.int64).tolist()
                      if i in mapper.landmarks and rec.index not in mapper.landmarks[i].obs], np.int64)
    if len(ids) == 0:
        return 0, 0
    rows = mapper.landmarks.rows
    lms = [mapper.landmarks[i] for i in ids.tolist()]
    if rows is not None:
        pos, desc = rows.pos[ids], rows.desc[ids]
    else:
        pos = np.array([lm.position for lm in lms], float).reshape(-1, 3)
        desc = np.array([lm.descriptor for lm in lms], np.uint8).reshape(-1, 32)
    ref = np.array([mapper.keyframes[min(lm.obs, key=lambda k: mapper.keyframes[k].order)].T_world_cam[:3, 3]
                    for lm in lms], float).reshape(-1, 3)
    q, r = fuse_matches(rec, pos, desc, ref, mapper.calib, scale, p.chi2_mono, p.pixel_sigma,
                        p.triangulate_max_hamming)
    added, merged, touched = 0, 0, []
    for qi, row in zip(q.tolist(), r.tolist()):
        lm = lms[qi]
        other = int(rec.landmark[row])
        if other < 0:
            lm.obs[rec.index] = row
            rec.landmark[row] = lm.id
            lm.visible += 1
            lm.found += 1
            touched.append(lm)
            added += 1
        elif other != lm.id and other in mapper.landmarks:
            keep = mapper.landmarks[other]
            if p.triangulate_fuse_merge:
                _merge(mapper, lm, keep)
                touched.append(keep)
            else:   # the duplicate only leaves the map
                mapper._delete_landmark(lm.id)
            merged += 1
    mapper._update_descriptors([lm for lm in touched if lm.id in mapper.landmarks])
    return added, merged


def _merge(mapper, gone, keep) -> None:
    """MapPoint::Replace: ``gone``'s observations move to ``keep`` (where ``keep`` has none in
    that keyframe) and ``gone`` leaves the map."""
    for k, i in list(gone.obs.items()):
        kf = mapper.keyframes[k]
        if k in keep.obs:
            kf.landmark[i] = -1
        else:
            keep.obs[k] = i
            kf.landmark[i] = keep.id
            keep.visible += 1
            keep.found += 1
    gone.obs.clear()
    mapper.landmarks.pop(gone.id)


@contextmanager
def hidden_from_ba(mapper, ids: np.ndarray):
    """Keep landmarks ``ids`` out of local BA: their keyframe rows read -1 inside the block
    (BA finds its points through the keyframes' ``landmark`` arrays) and are restored after."""
    hidden = []
    for lid in np.asarray(ids, np.int64).tolist():
        lm = mapper.landmarks.get(lid)
        if lm is None:
            continue
        for k, i in lm.obs.items():
            mapper.keyframes[k].landmark[i] = -1
        hidden.append(lm)
    try:
        yield
    finally:
        for lm in hidden:
            if lm.id in mapper.landmarks:
                for k, i in lm.obs.items():
                    mapper.keyframes[k].landmark[i] = lm.id
