"""Relocalisation by keyframe-database query (AGRI §3.4; ORB-SLAM Tracking::Relocalization).

``PlaceMemory`` is what tracking can find its way back to: keyframes (keypoints, stereo,
descriptors, the landmark each keypoint observes, pose), landmark positions and
descriptors, covisibility, and a bag-of-words database over the keyframes. It is filled
either from a saved map (``from_map``, for ``--load-map``) or, during a run, from the
tracker's own keyframes and the local-map updates (bag-of-words computed only when a
relocalisation needs it, so tracking pays nothing while it is not lost).

``relocalise(frame)``: the frame's ORB words query the database; for each candidate keyframe
(best score first) its keypoints' landmarks are matched to the frame by descriptor within a
vocabulary node, EPnP RANSAC gives a pose, the candidate's local map (it and its covisible
keyframes) is projected with it for more matches, and a motion-only stereo refinement
(AGRI Eq. 9, Huber) must keep ``reloc_min_inliers``. Not the motion model: this works after a
gap of any length, or for a camera carried elsewhere (kidnapped), as long as it sees a
mapped place again.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words, knn_match, match_in_window
from canopy.frontend.pose import refine_pose
from canopy.loop.database import KeyframeDatabase
from canopy.loop.detector import Covisibility
from canopy.loop.keyframe import PlaceKeyframe, with_bow
from canopy.loop.params import LoopParams
from canopy.loop.verify import _pnp_ransac, match_by_nodes
from shared.arrays import unique_sorted
from shared.types import StereoCalibration


@dataclass
class Relocalisation:
    T_world_cam: np.ndarray      # (4,4) pose of the frame in the map
    keyframe: int                # the map keyframe it was found against
    n_inliers: int
    landmark_ids: np.ndarray     # (N,) landmark observed by each keypoint of the frame (-1: none)
    candidates_tried: int


class PlaceMemory:
    def __init__(self, calib: StereoCalibration, params: LoopParams | None = None, vocabulary=None):
        self.calib = calib
        self.params = (params or LoopParams()).validate()
        self.vocabulary = vocabulary
        self.keyframes: dict[int, PlaceKeyframe] = {}
        self._covisibility = Covisibility()
        self._saved_covisibility = False    # a loaded map brings its counts; else counted on demand
        self.database = KeyframeDatabase()
        self._in_database: set[int] = set()
        self.lm_ids = np.zeros(0, np.int64)
        self.lm_pos = np.zeros((0, 3))
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []

    # ------------------------------------------------------------------ filling
    @classmethod
    def from_map(cls, data, params: LoopParams | None = None, vocabulary=None) -> "PlaceMemory":
        """A memory of a saved map (``canopy.loop.map_io.MapData``), database built at once."""
        mem = cls(data.calibration, params, vocabulary)
        depth = np.full(len(data.uv), -1.0)
        ok = data.u_right >= 0
        disparity = data.uv[:, 0] - data.u_right
        good = ok & (disparity > 1e-6)
        depth[good] = data.calibration.fx * data.calibration.baseline / disparity[good]
        for k, index in enumerate(data.kf_index.tolist()):
            rows = data.keyframe_rows(k)
            mem.add_keyframe(int(index), float(data.kf_timestamp[k]), data.kf_pose[k], data.uv[rows],
                             np.where(good[rows], data.u_right[rows], -1.0), depth[rows], data.octave[rows],
                             data.descriptors[rows], data.landmark[rows])
        mem.set_landmarks(data.lm_id, data.lm_position)
        # the saved covisibility (shared-landmark counts) instead of recounting every observation
        counts = mem._covisibility._counts
        for a, b, n in np.asarray(data.covisibility, np.int64).reshape(-1, 3).tolist():
            counts.setdefault(a, {})[b] = n
            counts.setdefault(b, {})[a] = n
        mem._saved_covisibility = True
        mem.build_database()
        return mem

    def add_keyframe(self, index: int, timestamp: float, T_world_cam, uv, u_right, depth, octave, descriptors,
                     landmark_ids) -> None:
        kf = PlaceKeyframe(index=int(index), timestamp=float(timestamp), T_world_cam=np.asarray(T_world_cam, float).copy(),
                           uv=np.asarray(uv, np.float64), u_right=np.asarray(u_right, np.float64),
                           depth=np.asarray(depth, np.float64), octave=np.asarray(octave, np.int64),
                           descriptors=np.asarray(descriptors, np.uint8), landmark_ids=np.asarray(landmark_ids, np.int64).copy())
        self.keyframes[kf.index] = kf

    def covisible(self, keyframe: int, n: int) -> list[int]:
        """The ``n`` keyframes sharing most landmarks with ``keyframe`` (at least
        ``covisibility_min_shared``): the saved counts of a loaded map, or counted now (adding a
        keyframe during a run stays free; a query costs one ``isin`` per keyframe)."""
        min_shared = self.params.covisibility_min_shared
        if self._saved_covisibility:
            return self._covisibility.best(keyframe, n, min_shared)
        mine = self.keyframes[keyframe].landmark_ids
        mine = unique_sorted(mine[mine >= 0])
        counts = [(int(np.isin(kf.landmark_ids, mine, assume_unique=False).sum()), k)
                  for k, kf in self.keyframes.items() if k != keyframe]
        counts = sorted(((c, k) for c, k in counts if c >= min_shared), key=lambda ck: (-ck[0], ck[1]))
        return [k for _, k in counts[:n]]

    def set_pose(self, index: int, T_world_cam) -> None:
        kf = self.keyframes.get(int(index))
        if kf is not None:
            kf.T_world_cam = np.asarray(T_world_cam, float).copy()

    def set_landmarks(self, ids, positions) -> None:
        """Newer positions win; merged lazily (an update costs a copy and a list append, a merge
        every ``MERGE_EVERY`` updates)."""
        self._pending.append((np.asarray(ids, np.int64).copy(), np.asarray(positions, np.float32).reshape(-1, 3).copy()))
        if len(self._pending) >= self.MERGE_EVERY:
            self._merge()

    MERGE_EVERY = 128

    def _merge(self) -> None:
        if not self._pending:
            return
        parts = self._pending[::-1] + [(self.lm_ids, self.lm_pos)]  # newest first
        ids = np.concatenate([p[0] for p in parts])
        _, first = np.unique(ids, return_index=True)
        self.lm_ids = ids[first]
        self.lm_pos = np.concatenate([np.asarray(p[1], np.float64) for p in parts])[first]
        self._pending = []

    def build_database(self) -> None:
        """Bag of words of every keyframe not yet in the database."""
        for k in sorted(set(self.keyframes) - self._in_database):
            kf = with_bow(self.keyframes[k], self.vocabulary)
            self.database.add(k, kf.bow, kf.line_bow, kf.stats)
            self._in_database.add(k)

    def __len__(self) -> int:
        return len(self.keyframes)

    def max_landmark_id(self) -> int:
        """The largest landmark id known (-1 if none); pending position updates included."""
        self._merge()
        return int(self.lm_ids.max()) if len(self.lm_ids) else -1

    # ------------------------------------------------------------------ lookups
    def positions_of(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mask of ``ids`` known, their positions)."""
        self._merge()
        ids = np.asarray(ids, np.int64)
        j = np.searchsorted(self.lm_ids, ids)
        j = np.clip(j, 0, max(len(self.lm_ids) - 1, 0))
        known = (ids >= 0) & (len(self.lm_ids) > 0) & (self.lm_ids[j] == ids) if len(self.lm_ids) else np.zeros(len(ids), bool)
        return known, self.lm_pos[j[known]] if len(self.lm_ids) else np.zeros((0, 3))

    def local_keyframes(self, centres, n: int | None = None) -> list[int]:
        """The keyframes ``centres`` and their best covisible neighbours (ORB-SLAM's local keyframes)."""
        n = self.params.fuse_neighbours if n is None else n
        out: list[int] = []
        for c in centres:
            for k in [int(c)] + self.covisible(int(c), n):
                if k in self.keyframes and k not in out:
                    out.append(k)
        return out

    def local_map(self, centres, n: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ids, positions, descriptors) of the landmarks seen by the local keyframes of ``centres``;
        a landmark's descriptor is that of its keypoint in the most central keyframe seeing it."""
        self._merge()
        kfs = self.local_keyframes(centres, n)
        if not kfs or not len(self.lm_ids):
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 32), np.uint8)
        all_ids = np.concatenate([self.keyframes[k].landmark_ids for k in kfs])
        all_desc = np.concatenate([self.keyframes[k].descriptors for k in kfs])
        ids, first = np.unique(all_ids, return_index=True)
        keep = ids >= 0
        ids, first = ids[keep], first[keep]
        j = np.clip(np.searchsorted(self.lm_ids, ids), 0, len(self.lm_ids) - 1)
        known = self.lm_ids[j] == ids
        return self.lm_ids[j[known]], self.lm_pos[j[known]], all_desc[first[known]]

    def best_keyframe(self, landmark_ids: np.ndarray) -> int | None:
        """The keyframe sharing the most of ``landmark_ids`` (ORB-SLAM: the reference keyframe of
        a frame is the one sharing most map points with it)."""
        ids = set(np.asarray(landmark_ids, np.int64)[np.asarray(landmark_ids) >= 0].tolist())
        if not ids:
            return None
        best, best_n = None, 0
        for k, kf in self.keyframes.items():
            n = len(ids.intersection(kf.landmark_ids.tolist()))
            if n > best_n or (n == best_n and best is not None and k > best):
                best, best_n = k, n
        return best

    # ------------------------------------------------------------------ relocalisation
    def relocalise(self, index: int, uv, u_right, depth, octave, descriptors) -> Relocalisation | None:
        """Pose of a frame in this memory's map, or None (see the module doc)."""
        p = self.params
        self.build_database()
        q = with_bow(PlaceKeyframe(index=int(index), timestamp=0.0, T_world_cam=np.eye(4), uv=np.asarray(uv, np.float64),
                                   u_right=np.asarray(u_right, np.float64), depth=np.asarray(depth, np.float64),
                                   octave=np.asarray(octave, np.int64), descriptors=np.asarray(descriptors, np.uint8),
                                   landmark_ids=np.full(len(uv), -1, np.int64)), self.vocabulary)
        if len(q) < p.min_matches or not q.bow:
            return None
        cands = self.database.query(q.bow, min_common_words_ratio=p.min_common_words_ratio)[:p.reloc_candidates]
        q_words = as_words(q.descriptors)
        sigma = p.pixel_sigma * p.scale_factor ** q.octave.astype(float)
        meas = np.concatenate([q.uv, q.u_right[:, None]], axis=1)
        has_right = q.depth > 0
        use_nodes = self.vocabulary is not None and hasattr(self.vocabulary, "node_ids") and len(q.word_ids) == len(q)
        for tried, c in enumerate(cands, 1):
            kf = self.keyframes[c.keyframe]
            known, Xw = self.positions_of(kf.landmark_ids)
            rows = np.flatnonzero(known)
            if len(rows) < p.min_matches:
                continue
            if use_nodes and len(kf.word_ids) == len(kf):
                lv = p.direct_index_levels_up
                qi, cj, _ = match_by_nodes(q.descriptors, np.asarray(self.vocabulary.node_ids(q.word_ids, lv), np.int64),
                                           kf.descriptors[rows],
                                           np.asarray(self.vocabulary.node_ids(kf.word_ids[rows], lv), np.int64),
                                           p.max_hamming, p.match_ratio)
            else:
                qi, cj, _ = knn_match(q.descriptors, kf.descriptors[rows], p.max_hamming, p.match_ratio)
            if len(qi) < p.min_matches:
                continue
            T_cw, mask = _pnp_ransac(Xw[cj], q.uv[qi], self.calib.K, p, seed=index * 7919 + c.keyframe)
            if T_cw is None or mask.sum() < p.min_pnp_inliers:
                continue
            est = refine_pose(T_cw, Xw[cj][mask], meas[qi[mask]], has_right[qi[mask]], sigma[qi[mask]], self.calib,
                              p.refine_rounds, p.refine_iterations, p.chi2_mono, p.chi2_stereo)
            # more matches from the candidate's local map, projected with that pose
            ids, pos, desc = self.local_map([c.keyframe])
            T_cw = est.T_cam_world
            Pc = pos @ T_cw[:3, :3].T + T_cw[:3, 3]
            z = np.where(Pc[:, 2] > 0.1, Pc[:, 2], np.nan)
            proj = np.stack([self.calib.fx * Pc[:, 0] / z + self.calib.cx, self.calib.fy * Pc[:, 1] / z + self.calib.cy], 1)
            in_view = (np.isfinite(proj).all(axis=1) & (proj[:, 0] >= 0) & (proj[:, 0] < self.calib.width)
                       & (proj[:, 1] >= 0) & (proj[:, 1] < self.calib.height))
            proj = np.where(in_view[:, None], proj, -1e6)
            g_l, g_q, _ = match_in_window(proj, as_words(desc), np.full(len(ids), p.guided_search_radius), q.uv, q_words,
                                          p.max_hamming, p.match_ratio, q_mask=in_view)
            lm_of_q = np.full(len(q), -1, np.int64)
            if len(g_q) >= est.inliers.sum():
                est = refine_pose(T_cw, pos[g_l], meas[g_q], has_right[g_q], sigma[g_q], self.calib, p.refine_rounds,
                                  p.refine_iterations, p.chi2_mono, p.chi2_stereo)
                lm_of_q[g_q[est.inliers]] = ids[g_l[est.inliers]]
            else:
                sel = np.flatnonzero(mask)
                lm_of_q[qi[sel][est.inliers]] = kf.landmark_ids[rows[cj[sel][est.inliers]]]
            n_inl = int(est.inliers.sum())
            if n_inl >= p.reloc_min_inliers:
                return Relocalisation(se3_inv(est.T_cam_world), c.keyframe, n_inl, lm_of_q, tried)
        return None
