"""Loop detection over keyframes (AGRI §3.4.1; ORB-SLAM LoopClosing::DetectLoop).

Per new keyframe:

1. covisibility: keyframes sharing landmarks with it (from the landmark ids its keypoints
   observe); its neighbours are never loop candidates, and the lowest score between it and
   a neighbour is the bar a candidate must clear (a loop must look at least as alike as
   the views right next to it);
2. the database returns keyframes sharing enough words and clearing that bar; each
   candidate's covisibility group accumulates the scores of its members, and groups below
   ``group_score_ratio`` of the best are dropped (the best member of each group stays);
3. temporal consistency: a candidate group must overlap a group that was a candidate for
   the previous keyframe, for ``consistency_keyframes`` consecutive keyframes;
4. consistent candidates are verified geometrically (``verify_candidate``), best first.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.loop.database import KeyframeDatabase
from canopy.loop.keyframe import PlaceKeyframe
from canopy.loop.params import LoopParams
from canopy.loop.verify import LoopConstraint, verify_candidate
from shared.arrays import unique_sorted
from shared.types import StereoCalibration


class Covisibility:
    """Landmark observations of keyframes -> shared-landmark counts between keyframes."""

    def __init__(self):
        self._observers: dict[int, list[int]] = {}     # landmark -> keyframes
        self._counts: dict[int, dict[int, int]] = {}   # keyframe -> {keyframe: shared landmarks}

    def add(self, kf: int, landmark_ids: np.ndarray) -> None:
        ids = np.asarray(landmark_ids, np.int64)
        mine = self._counts.setdefault(kf, {})
        others: list[int] = []
        get = self._observers.get
        for lid in unique_sorted(ids[ids >= 0]).tolist():
            obs = get(lid)
            if obs is None:
                self._observers[lid] = [kf]
            elif kf not in obs:
                others.extend(obs)
                obs.append(kf)
        if not others:
            return
        ks, n = np.unique(np.asarray(others, np.int64), return_counts=True)  # shared landmarks per keyframe
        for other, shared in zip(ks.tolist(), n.tolist()):
            mine[other] = mine.get(other, 0) + shared
            theirs = self._counts.setdefault(other, {})
            theirs[kf] = theirs.get(kf, 0) + shared

    def neighbours(self, kf: int, min_shared: int) -> dict[int, int]:
        return {k: n for k, n in self._counts.get(kf, {}).items() if n >= min_shared}

    def best(self, kf: int, n: int, min_shared: int) -> list[int]:
        nb = self.neighbours(kf, min_shared)
        return sorted(nb, key=lambda k: (-nb[k], k))[:n]

    def pairs(self) -> dict[tuple[int, int], int]:
        """Every covisible pair (a < b) with its shared-landmark count."""
        return {(a, b): n for a, row in self._counts.items() for b, n in row.items() if a < b}


@dataclass
class DetectionStats:
    keyframes: int = 0
    queries: int = 0
    candidates: int = 0
    consistent: int = 0
    verified: int = 0
    rejected: dict = field(default_factory=dict)   # reason (first words) -> count


class LoopDetector:
    def __init__(self, calib: StereoCalibration, params: LoopParams | None = None, vocabulary=None,
                 plausible=None):
        """``plausible(constraint) -> str``: "" to accept a verified constraint, else why not
        (the loop closer checks it against the drift the map can have)."""
        self.calib = calib
        self.plausible = plausible
        self.params = (params or LoopParams()).validate()
        self.vocabulary = vocabulary
        self.database = KeyframeDatabase()
        self.keyframes: dict[int, PlaceKeyframe] = {}
        self.covisibility = Covisibility()
        self._order: list[int] = []
        self._path: dict[int, float] = {}   # distance travelled up to each keyframe (m)
        self._known: set[int] = set()       # keyframes of a loaded map (add_known_keyframe)
        self._last_loop_order = -10**9
        self._consistent_groups: list[tuple[set[int], int]] = []  # (group, consecutive count)
        self.stats = DetectionStats()

    def group_of(self, kf: int) -> set[int]:
        return {kf, *self.covisibility.neighbours(kf, self.params.covisibility_min_shared)}

    def add_keyframe(self, kf: PlaceKeyframe) -> LoopConstraint | None:
        """Store ``kf`` and return a verified loop constraint if it closes one."""
        p = self.params
        self._store(kf)
        self.stats.keyframes += 1
        constraint = None
        if len(self._order) - 1 - self._last_loop_order > p.min_keyframes_since_loop and kf.bow:
            constraint = self._detect(kf)
        self.database.add(kf.index, kf.bow, kf.line_bow, kf.stats)
        if constraint is not None:
            self._last_loop_order = len(self._order) - 1
            self._consistent_groups = []
        return constraint

    def _store(self, kf: PlaceKeyframe, known: bool = False) -> None:
        self.keyframes[kf.index] = kf
        self.covisibility.add(kf.index, kf.landmark_ids)
        if self._order and not known and self._order[-1] in self._known:
            # the first keyframe of a run extending a loaded map: it was found somewhere along the
            # loaded path, not after its end; the distance travelled continues from the nearest
            # loaded keyframe (else re-travelling the loaded map's end counts as path, and a view a
            # few metres down the same row passed min_loop_path_m as a "loop")
            known_kfs = list(self._known)
            P = np.array([self.keyframes[k].T_world_cam[:3, 3] for k in known_kfs])
            nearest = known_kfs[int(np.argmin(np.linalg.norm(P - kf.T_world_cam[:3, 3], axis=1)))]
            self._path[kf.index] = self._path[nearest]
        elif self._order:
            prev = self.keyframes[self._order[-1]].T_world_cam
            self._path[kf.index] = self._path[self._order[-1]] + float(np.linalg.norm(kf.T_world_cam[:3, 3] - prev[:3, 3]))
        else:
            self._path[kf.index] = 0.0
        self._order.append(kf.index)
        if known:
            self._known.add(kf.index)

    def add_known_keyframe(self, kf: PlaceKeyframe) -> None:
        """A keyframe of a loaded map (``--load-map``): stored and in the database, so later
        keyframes can close loops against it, but not itself a query (the map it comes from
        was already made consistent by the run that saved it)."""
        self._store(kf, known=True)
        self.database.add(kf.index, kf.bow, kf.line_bow, kf.stats)

    def _candidates(self, kf: PlaceKeyframe) -> list[int]:
        p = self.params
        neighbours = self.covisibility.neighbours(kf.index, p.covisibility_min_shared)
        if not neighbours:
            return []
        scores = self.database.scores(kf.bow, kf.line_bow, kf.stats)   # one pass: neighbours and candidates
        in_db = [k for k in neighbours if k in self.database]
        min_score = min(scores.get(k, (0.0, 0))[0] for k in in_db) if in_db else 0.0
        recent = set(self._order[-p.exclude_recent_keyframes - 1:])
        here = self._path[kf.index]
        recent |= {k for k in self._order if here - self._path[k] < p.min_loop_path_m}
        exclude = set(neighbours) | recent | {kf.index}
        cands = self.database.query(kf.bow, kf.line_bow, kf.stats, exclude=exclude,
                                    min_score=p.min_score_factor * min_score,
                                    min_common_words_ratio=p.min_common_words_ratio, scores=scores)
        if not cands:
            return []
        score = {c.keyframe: c.score for c in cands}
        groups = []
        for c in cands:  # accumulate over the candidate's best covisible neighbours that scored too
            members = [c.keyframe] + self.covisibility.best(c.keyframe, p.group_size, p.covisibility_min_shared)
            scored = [m for m in members if m in score]
            acc = sum(score[m] for m in scored)
            groups.append((acc, max(scored, key=lambda m: score[m])))
        best_acc = max(g[0] for g in groups)
        kept = sorted({g[1] for g in groups if g[0] >= p.group_score_ratio * best_acc},
                      key=lambda k: (-score[k], k))
        return kept

    def verify(self, query: PlaceKeyframe, cand: PlaceKeyframe):
        """Geometric verification of one candidate (stereo PnP; the monocular detector
        overrides it with PnP + Sim(3), ``canopy.loop.mono``)."""
        return verify_candidate(query, cand, self.calib, self.params, self.vocabulary)

    def _detect(self, kf: PlaceKeyframe) -> LoopConstraint | None:
        p = self.params
        self.stats.queries += 1
        candidates = self._candidates(kf)
        self.stats.candidates += len(candidates)
        # temporal consistency (ORB-SLAM mvConsistentGroups), counted in keyframes seen in a row
        current: list[tuple[set[int], int]] = []
        consistent: list[int] = []
        for c in candidates:
            group = self.group_of(c)
            count = 1
            for prev_group, prev_count in self._consistent_groups:
                if group & prev_group:
                    count = max(count, prev_count + 1)
            current.append((group, count))
            if count >= p.consistency_keyframes:
                consistent.append(c)
        self._consistent_groups = current
        self.stats.consistent += len(consistent)
        for c in consistent:
            v = self.verify(kf, self.keyframes[c])
            reason = v.kind
            if v.constraint is not None:
                why = self.plausible(v.constraint) if self.plausible is not None else ""
                if not why:
                    self.stats.verified += 1
                    return v.constraint
                reason = why
            self.stats.rejected[reason] = self.stats.rejected.get(reason, 0) + 1
        return None
