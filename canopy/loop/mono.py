"""Monocular loop closing and relocalisation on the stereo machinery (issue 13; ORB-SLAM
monocular, Mur-Artal et al. T-RO 2015 §VI-§VII).

What is shared with stereo: the keyframe database and the detector (covisibility, score
bar, groups, temporal consistency), the PnP verification with guided search
(``verify_candidate``), the drift gate and the essential graph. What differs, because a
monocular map has no metric scale and its scale drifts:

* a monocular ``PlaceKeyframe`` carries in ``depth`` the depth of the map point each
  keypoint observes (not a stereo measurement), so ``points_cam`` gives its map points in
  the keyframe's camera frame and map units;
* verification (``verify_candidate_mono``, ORB-SLAM ComputeSim3): 3D-2D PnP of the
  candidate's map points against the query's keypoints (the query as a plain monocular
  frame), then a Sim(3) between the two keyframes' matched point sets (Horn/Umeyama with
  scale in RANSAC, ``canopy.loop.sim3``), which must agree with the PnP rotation; the
  constraint is the similarity ``S_cand_query`` (PnP rotation and translation, Sim(3) scale);
* the pose graph is over Sim(3) (``optimise_sim3_pose_graph``) and the map is corrected by
  similarities (``apply_sim3_correction``): points scale with their reference keyframe.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from canopy.frontend.geometry import rotation_angle
from canopy.loop.closer import LoopCloser
from canopy.loop.correction import _apply
from canopy.loop.database import FeatureStats
from canopy.loop.detector import LoopDetector
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from canopy.loop.pose_graph import COVISIBILITY, LOOP, ODOMETRY, PoseGraphEdge, correction_for
from canopy.loop.sim3 import (estimate_sim3_ransac, optimise_sim3_pose_graph, rigid_pose, sim3_corrections,
                              sim3_matrix, sim3_parts)
from canopy.loop.verify import LoopConstraint, Verification, verify_candidate
from canopy.mono.params import MonoParams
from shared.types import StereoCalibration


@dataclass
class MonoLoopConstraint(LoopConstraint):
    scale: float = 1.0                        # query map units -> candidate map units
    S_cand_query: np.ndarray | None = None    # (4,4) similarity: query camera -> candidate camera


def as_monocular_query(kf: PlaceKeyframe) -> PlaceKeyframe:
    """The keyframe as a frame with keypoints only: its map-point depths are not measurements."""
    n = len(kf)
    return replace(kf, depth=np.full(n, -1.0), u_right=np.full(n, -1.0))


def verify_candidate_mono(query: PlaceKeyframe, cand: PlaceKeyframe, calib: StereoCalibration, params: LoopParams,
                          mono: MonoParams, vocabulary=None) -> Verification:
    """PnP (the stereo verification, candidate map points -> query pixels) + Sim(3) between
    the matched map points of both keyframes (see module doc)."""
    v = verify_candidate(as_monocular_query(query), cand, calib, params, vocabulary)
    if v.constraint is None:
        return v
    c = v.constraint
    qk, ck = np.asarray(c.query_keypoints), np.asarray(c.candidate_keypoints)
    both = query.has_depth[qk] & cand.has_depth[ck]
    qk, ck = qk[both], ck[both]
    octave = np.maximum(np.asarray(query.octave)[qk], np.asarray(cand.octave)[ck]).astype(float)
    gate = mono.sim3_chi2 * (params.pixel_sigma * params.scale_factor ** octave) ** 2
    est = estimate_sim3_ransac(query.points_cam(calib)[qk], cand.points_cam(calib)[ck], query.uv[qk], cand.uv[ck],
                               calib.K, gate, mono.sim3_iterations, mono.sim3_min_inliers,
                               seed=query.index * 7919 + cand.index, max_rel_3d=mono.sim3_max_relative_3d_error)
    if est.S is None:
        return Verification(None, f"Sim(3): {est.reason}", v.n_matches, v.n_inliers)
    R_s, _, s = sim3_parts(est.S)
    T_cq = c.T_cand_query
    disagreement = float(np.degrees(rotation_angle(R_s.T @ T_cq[:3, :3])))
    if disagreement > mono.sim3_max_rotation_disagreement_deg:
        return Verification(None, f"Sim(3) rotation {disagreement:.1f} deg from the PnP one", v.n_matches, v.n_inliers)
    x = mono.loop_max_scale_change
    if not (1.0 / (1.0 + x) <= s <= 1.0 + x):
        return Verification(None, f"Sim(3) scale {s:.3f} outside [{1 / (1 + x):.2f}, {1 + x:.2f}]", v.n_matches,
                            v.n_inliers)
    S_cq = sim3_matrix(T_cq[:3, :3], T_cq[:3, 3], s)
    mc = MonoLoopConstraint(**vars(c), scale=float(s), S_cand_query=S_cq)
    return Verification(mc, "ok", v.n_matches, v.n_inliers)


class MonoLoopDetector(LoopDetector):
    """The stereo detector with the monocular verification."""

    def __init__(self, calib: StereoCalibration, params: LoopParams | None = None, vocabulary=None, plausible=None,
                 mono: MonoParams | None = None):
        super().__init__(calib, params, vocabulary, plausible)
        self.mono = mono or MonoParams()

    def verify(self, query: PlaceKeyframe, cand: PlaceKeyframe) -> Verification:
        return verify_candidate_mono(query, cand, self.calib, self.params, self.mono, self.vocabulary)


class MonoLoopCloser(LoopCloser):
    """``LoopCloser`` whose loop edges are similarities and whose pose graph is Sim(3).

    ``closure.corrections`` are similarities C_k (points: X' = C_k X; poses:
    ``rigid_pose(C_k T)``), to be applied with ``apply_sim3_correction``; ``self.poses`` stay
    rigid camera poses (the keyframes' poses in the corrected map)."""

    def __init__(self, calib: StereoCalibration, params: LoopParams | None = None, vocabulary=None,
                 mono: MonoParams | None = None):
        super().__init__(calib, params, vocabulary)
        # landmark fusion and the full BA after a loop are stereo (rigid corrections, stereo
        # factors); a monocular map is corrected by similarities only
        # (and its keyframes carry map-point depths with no right column: keep them)
        self.params = replace(self.params, fuse=False, full_ba=False, verify_stereo_only=False)
        self.mono = mono or MonoParams()
        self.detector = MonoLoopDetector(calib, self.params, vocabulary, plausible=self.drift_check, mono=self.mono)

    def graph_sigmas(self) -> dict[str, tuple[float, float, float]]:
        p, ss = self.params, self.mono.sigma_log_scale
        return {ODOMETRY: (p.odometry_sigma_rot, p.odometry_sigma_trans, ss),
                COVISIBILITY: (p.odometry_sigma_rot, p.odometry_sigma_trans, ss),
                LOOP: (p.loop_sigma_rot, p.loop_sigma_trans, ss)}

    def loop_measurement(self, constraint: MonoLoopConstraint) -> np.ndarray:
        return constraint.S_cand_query

    def optimise(self, before: dict[int, np.ndarray], edges: list[PoseGraphEdge], fixed: int):
        """Sim(3) pose graph; the keyframes keep rigid poses, the corrections are similarities."""
        p = self.params
        result = optimise_sim3_pose_graph(before, edges, self.graph_sigmas(), p.robust_kernel_k, p.pgo_max_iterations,
                                          fixed=fixed)
        after = {k: rigid_pose(S) for k, S in result.poses.items()}
        return after, sim3_corrections(before, result.poses), (result.initial_error, result.final_error)


# --------------------------------------------------------------------------- the map side

def place_keyframe_from_mono_map(kf_data, mapper) -> PlaceKeyframe:
    """The loop closer's view of a keyframe the monocular mapper has just inserted: tracking's
    keypoints, the landmark each observes and, in ``depth``, that landmark's depth in this
    keyframe's camera (-1 where none or behind)."""
    rec = mapper.keyframes[kf_data.index]
    lm_ids = np.asarray(rec.landmark, np.int64).copy()
    depth = np.full(len(lm_ids), -1.0)
    has = np.flatnonzero(lm_ids >= 0)
    if len(has):
        P = np.array([mapper.landmarks[int(l)].position for l in lm_ids[has]], float)
        T = rec.T_world_cam
        z = (P - T[:3, 3]) @ T[:3, 2]       # depth along the optical axis: (R^T (P - t))_z
        depth[has] = np.where(z > 0, z, -1.0)
    return PlaceKeyframe(index=int(kf_data.index), timestamp=float(kf_data.timestamp),
                         T_world_cam=rec.T_world_cam.copy(), uv=np.asarray(kf_data.uv, np.float64),
                         u_right=np.full(len(lm_ids), -1.0), depth=depth,
                         octave=np.asarray(kf_data.octave, np.int64), descriptors=np.asarray(kf_data.descriptors, np.uint8),
                         landmark_ids=lm_ids, stats=FeatureStats.of(np.zeros((0, 2))))


def apply_sim3_correction(mapper, corrections: dict[int, np.ndarray]) -> int:
    """ORB-SLAM CorrectLoop with similarities: each keyframe's pose becomes
    ``rigid_pose(C T)``, each landmark moves (and scales) with its reference keyframe, the
    first that observed it: X' = C_ref X. Returns the number of keyframes moved."""
    if not corrections:
        return 0
    for k, rec in mapper.keyframes.items():
        rec.T_world_cam = rigid_pose(correction_for(int(k), corrections) @ rec.T_world_cam)
    for lm in mapper.landmarks.values():
        if lm.obs:
            lm.position = _apply(correction_for(int(min(lm.obs)), corrections), np.asarray(lm.position, float))
    return len(mapper.keyframes)


def relocalise_mono(frame: PlaceKeyframe, detector: LoopDetector, keyframe_poses: dict[int, np.ndarray],
                    calib: StereoCalibration, params: LoopParams, max_candidates: int = 3):
    """Relocalisation of a lost monocular frame (ORB-SLAM Relocalization): the keyframe
    database ranks the stored keyframes by bag-of-words score; the best ``max_candidates``
    are tried with the PnP verification (their map points against the frame's keypoints).
    Returns (T_world_cam, candidate keyframe, inliers) of the first with at least
    ``reloc_min_inliers``, or None. ``keyframe_poses``: the map's current keyframe poses."""
    if not frame.bow or not len(detector.database):
        return None
    cands = detector.database.query(frame.bow, None, None, exclude=set(), min_score=0.0,
                                    min_common_words_ratio=params.min_common_words_ratio)
    query = as_monocular_query(frame)
    for c in cands[:max_candidates]:
        if c.keyframe not in keyframe_poses or c.keyframe not in detector.keyframes:
            continue
        v = verify_candidate(query, detector.keyframes[c.keyframe], calib, params, detector.vocabulary)
        if v.constraint is not None and v.n_inliers >= params.reloc_min_inliers:
            return keyframe_poses[c.keyframe] @ v.constraint.T_cand_query, c.keyframe, v.n_inliers
    return None


# --------------------------------------------------------------------------- actor hooks

def mono_loop_keyframe_message(kf, mapper, update):
    """Local mapping -> loop closing for a monocular keyframe: as ``loop_keyframe_message``,
    with the depth of each keypoint's map point in ``depth`` (``place_keyframe_from_mono_map``)."""
    from protocol.messages import LoopKeyframe

    place = place_keyframe_from_mono_map(kf, mapper)
    return LoopKeyframe(index=place.index, timestamp=place.timestamp, T_world_cam=place.T_world_cam,
                        uv=np.asarray(place.uv, np.float32), u_right=np.asarray(place.u_right, np.float32),
                        depth=np.asarray(place.depth, np.float32), octave=np.asarray(place.octave, np.int32),
                        descriptors=place.descriptors, landmark_ids=place.landmark_ids,
                        window_poses={int(k): np.asarray(T, float) for k, T in update.keyframe_poses.items()},
                        sent_at=time.time())


def apply_mono_loop_result(mapper, result, update) -> bool:
    """``apply_loop_result`` for a monocular map: similarities applied (``apply_sim3_correction``),
    the loop's two sides fused, ``update`` re-read from the corrected map."""
    from canopy.loop.correction import corrections_from_arrays, refresh_update

    if not result.closed or len(result.keyframe_ids) == 0:
        return False
    apply_sim3_correction(mapper, corrections_from_arrays(result.keyframe_ids, result.corrections))
    if result.candidate is not None and int(result.candidate) >= 0:
        mapper.fuse_loop(int(result.keyframe_index), int(result.candidate))
    if update is not None:
        refresh_update(mapper, update)
    return True


def make_mono_relocaliser(closer: MonoLoopCloser, mapper, vocabulary, max_candidates: int = 3):
    """The ``MonoTracker.relocaliser`` of an in-process run: the lost frame's keypoints as a
    place query (``relocalise_mono`` against the loop closer's database, with the map's
    current keyframe poses), answered with the local map around the keyframe it matched."""
    from canopy.loop.keyframe import with_bow

    def relocalise(frame, feats):
        n = len(feats)
        if n == 0:
            return None
        place = with_bow(PlaceKeyframe(index=int(frame.index), timestamp=float(frame.timestamp), T_world_cam=np.eye(4),
                                       uv=np.asarray(feats.uv, np.float64), u_right=np.full(n, -1.0),
                                       depth=np.full(n, -1.0), octave=np.asarray(feats.octave, np.int64),
                                       descriptors=np.asarray(feats.descriptors, np.uint8),
                                       landmark_ids=np.full(n, -1, np.int64)), vocabulary)
        found = relocalise_mono(place, closer.detector, mapper.keyframe_poses(), closer.detector.calib,
                                closer.params, max_candidates)
        if found is None:
            return None
        T_wc, kf, _ = found
        return T_wc, kf, mapper.local_map_around(kf)

    return relocalise
