"""The map's records (the keyframe and landmark stores of ``LocalMapper``).

``LocalMapper.keyframes: dict[int, Keyframe]`` (by frame index), ``LocalMapper.landmarks:
dict[int, Landmark]`` and ``LocalMapper.lines: dict[int, LineLandmark]`` (by id) are the
whole map. A landmark's ``obs`` maps keyframe index -> keypoint row and the keyframe's
``landmark`` array is the reverse index; both are kept in step by every change.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from itertools import chain
from operator import attrgetter

import numpy as np

from shared.arrays import unique_sorted


@dataclass
class Keyframe:
    index: int
    timestamp: float
    T_world_cam: np.ndarray
    uv: np.ndarray
    u_right: np.ndarray
    octave: np.ndarray
    descriptors: np.ndarray
    landmark: np.ndarray      # (N,) landmark id observed by keypoint i, -1 for none
    segment: int
    order: int                # insertion counter (ages of landmarks are counted in keyframes)
    # line observations (empty without lines): infinite lines of the left / right segments
    line_coeffs: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    line_coeffs_right: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # NaN: no stereo
    # the observed segments (x1, y1, x2, y2) px: their endpoints hold the landmark's extent in BA
    line_segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    line_segments_right: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))  # NaN: no stereo
    line_descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    line_landmark: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


class Landmark:
    """A map point: world position, distinctive descriptor, observations (keyframe index ->
    keypoint row) and ORB-SLAM's found / visible counts.

    In a ``LandmarkStore`` (``LocalMapper.landmarks``) the position and descriptor live in the
    store's id-indexed arrays (``LandmarkRows``), so the per-keyframe work over thousands of
    landmarks (the local map for tracking, local BA's points, ``map_points``) gathers and
    scatters rows instead of walking Python objects (issue 8). ``position`` / ``descriptor`` read
    a copy and assigning them writes the row: the same values either way, and a position read
    before a BA keeps its value (as the array a landmark used to hold did)."""

    __slots__ = ("id", "obs", "first_order", "segment", "visible", "found", "_rows", "_position", "_descriptor")

    def __init__(self, id: int, position, descriptor, obs: dict[int, int] | None = None, first_order: int = 0,
                 segment: int = 0, visible: int = 1, found: int = 1):
        self.id = id
        self.obs = {} if obs is None else obs
        self.first_order = first_order
        self.segment = segment
        self.visible = visible
        self.found = found
        self._rows = None
        self._position = position
        self._descriptor = descriptor

    @property
    def position(self) -> np.ndarray:
        return self._position if self._rows is None else self._rows.pos[self.id].copy()

    @position.setter
    def position(self, value) -> None:
        if self._rows is None:
            self._position = value
        else:
            self._rows.pos[self.id] = value

    @property
    def descriptor(self) -> np.ndarray:
        return self._descriptor if self._rows is None else self._rows.desc[self.id].copy()

    @descriptor.setter
    def descriptor(self, value) -> None:
        if self._rows is None:
            self._descriptor = value
        else:
            self._rows.desc[self.id] = value

    def _attach(self, rows: "LandmarkRows | None") -> None:
        """Keep position and descriptor in ``rows`` (None: in the object again)."""
        if rows is self._rows:
            return
        pos, desc = self.position, self.descriptor
        self._rows = None
        if rows is not None:
            rows.pos[self.id] = pos
            rows.desc[self.id] = desc
            self._rows, self._position, self._descriptor = rows, None, None
        else:
            self._position, self._descriptor = pos, desc

    def __getstate__(self):   # a pickled landmark carries its values, not its store's arrays
        return {k: getattr(self, k) for k in ("id", "obs", "first_order", "segment", "visible", "found",
                                               "position", "descriptor")}

    def __setstate__(self, state) -> None:
        self.__init__(state["id"], state["position"], state["descriptor"], state["obs"], state["first_order"],
                      state["segment"], state["visible"], state["found"])

    def __repr__(self) -> str:
        return (f"Landmark(id={self.id}, position={self.position!r}, obs={self.obs!r}, "
                f"first_order={self.first_order}, segment={self.segment}, visible={self.visible}, found={self.found})")


class LandmarkRows:
    """Positions (float64) and descriptors (uint8 x 32) of landmarks in arrays indexed by the
    landmark id (tracking numbers landmarks with a counter, so the ids are dense). Rows of
    landmarks no longer in the map keep stale values: read only rows of present ids."""

    def __init__(self):
        self.pos = np.zeros((0, 3))
        self.desc = np.zeros((0, 32), np.uint8)

    def reserve(self, top: int) -> None:
        """Room for ids up to ``top`` (capacity doubles: amortised O(1) per landmark)."""
        if top < len(self.pos):
            return
        n = max(top + 1, 2 * len(self.pos), 1024)
        pos, desc = np.zeros((n, 3)), np.zeros((n, 32), np.uint8)
        pos[: len(self.pos)] = self.pos
        desc[: len(self.desc)] = self.desc
        self.pos, self.desc = pos, desc


class LandmarkStore(dict):
    """``LocalMapper.landmarks``: a dict id -> ``Landmark`` whose landmarks keep position and
    descriptor in ``rows`` (attached on assignment, so a map restored from a file or a test's
    hand-made landmark is stored the same way). Bulk readers use ``rows`` when it is not None;
    an id far beyond the dense counter's range (``_SPARSE``) turns the arrays off for good and
    every landmark holds its values again."""

    def __init__(self):
        super().__init__()
        self.rows: LandmarkRows | None = LandmarkRows()

    def __setitem__(self, lid, lm) -> None:
        if self.rows is not None and (lid != lm.id or lid < 0 or lid > _SPARSE * (len(self) + 1) + (1 << 20)):
            for other in self.values():
                other._attach(None)
            self.rows = None
        if self.rows is not None:
            self.rows.reserve(lid)
        lm._attach(self.rows)
        super().__setitem__(lid, lm)

    def add_new(self, landmarks: list, positions: np.ndarray, descriptors: np.ndarray) -> None:
        """Store new landmarks (built with position and descriptor None) whose values are the rows
        of ``positions`` / ``descriptors``: two array writes instead of a row write per landmark."""
        ids = np.fromiter(map(_ID, landmarks), np.int64, len(landmarks))
        dense = self.rows is not None and (len(ids) == 0 or (int(ids.min()) >= 0 and int(ids.max()) <= _SPARSE * (
            len(self) + len(ids) + 1) + (1 << 20)))
        if not dense:
            for lm, p, d in zip(landmarks, positions, descriptors):
                lm._position, lm._descriptor = p, d
                self[lm.id] = lm
            return
        rows = self.rows
        if len(ids):
            rows.reserve(int(ids.max()))
        rows.pos[ids] = positions
        rows.desc[ids] = descriptors
        for lm in landmarks:
            lm._rows = rows
        dict.update(self, zip(ids.tolist(), landmarks))

    def update(self, *args, **kwargs) -> None:
        for lid, lm in dict(*args, **kwargs).items():
            self[lid] = lm

    def setdefault(self, lid, lm=None):
        if lid not in self:
            self[lid] = lm
        return self[lid]


_SPARSE = 64
_ID = attrgetter("id")
_OBS = attrgetter("obs")


@dataclass
class LineLandmark:
    id: int
    endpoints: np.ndarray                              # (2,3) A, B in world
    descriptor: np.ndarray                             # (32,) LBD of the latest observation
    obs: dict[int, int] = field(default_factory=dict)  # keyframe index -> line row
    first_order: int = 0
    segment: int = 0


def _sorted_unique_ids(ids: np.ndarray) -> np.ndarray:
    """Sorted distinct non-negative ids (what ``np.unique`` gives, -1 = none dropped). Landmark
    ids are a dense counter, so a presence table is ~10x cheaper than sorting the window's
    ~36 k keypoint slots (KITTI: 2 -> 0.2 ms per keyframe); sparse ids fall back to np.unique."""
    ids = np.asarray(ids, np.int64)
    ids = ids[ids >= 0]
    if len(ids) == 0:
        return ids
    top = int(ids.max())
    if top > 64 * len(ids) + 4096:
        return unique_sorted(ids)
    present = np.zeros(top + 1, bool)
    present[ids] = True
    return np.flatnonzero(present).astype(np.int64)


class ObservationTable:
    """The observations (keyframe, keypoint row) of a set of landmarks as arrays, read from their
    ``obs`` dicts once and then selected, counted and grouped by gathers (issue 8).

    Why: one keyframe's steps read the same landmarks' observations several times with no change
    in between: the distinctive descriptors and the covisibility counts (the new keyframe's
    landmarks), the window's fixed set and local BA's edges (the window's landmarks). Each step
    chained the dicts again (``np.fromiter`` over ~10^5 dict entries per EuRoC hover keyframe,
    ~5 ms); the table chains each landmark once. Each landmark's rows are contiguous (a group) and
    in its dict's (insertion) order, so a selection gives the same arrays as chaining the dicts.

    The table is a snapshot: whoever changes observations while it is in use says so
    (``drop_keyframe`` for keyframe culling) or builds a new one; ``LocalMapper.insert_keyframe``
    uses one from its insertion to local BA's edges and one for keyframe culling."""

    def __init__(self, landmarks, ids=()):
        self._landmarks = landmarks
        self.ids = np.zeros(0, np.int64)     # landmark of each group
        self.start = np.zeros(0, np.int64)   # its first row
        self.count = np.zeros(0, np.int64)   # its rows
        self.kf = np.zeros(0, np.int64)
        self.kp = np.zeros(0, np.int64)
        self._order = self._sorted = np.zeros(0, np.int64)   # ids sorted, for lookups
        self.add(ids)

    def contains(self, ids) -> np.ndarray:
        ids = np.asarray(ids, np.int64)
        if len(self._sorted) == 0:
            return np.zeros(len(ids), bool)
        pos = np.minimum(np.searchsorted(self._sorted, ids), len(self._sorted) - 1)
        return self._sorted[pos] == ids

    def add(self, ids) -> None:
        """Chain the observations of landmarks ``ids`` (in the store) not in the table yet."""
        ids = np.asarray(ids, np.int64)
        ids = unique_sorted(ids[~self.contains(ids)]) if len(self.ids) else unique_sorted(ids)
        if len(ids) == 0:
            return
        obs = list(map(_OBS, map(self._landmarks.__getitem__, ids.tolist())))
        n = np.fromiter(map(len, obs), np.int64, len(obs))
        total = int(n.sum())
        kf = np.fromiter(chain.from_iterable(obs), np.int64, total)
        kp = np.fromiter(chain.from_iterable(map(dict.values, obs)), np.int64, total)
        self.start = np.concatenate([self.start, len(self.kf) + np.cumsum(n) - n])
        self.count = np.concatenate([self.count, n])
        self.ids = np.concatenate([self.ids, ids])
        self.kf, self.kp = np.concatenate([self.kf, kf]), np.concatenate([self.kp, kp])
        self._order = np.argsort(self.ids, kind="stable")
        self._sorted = self.ids[self._order]

    def groups(self, ids) -> np.ndarray:
        """Group index of each of ``ids`` (every one in the table)."""
        return self._order[np.searchsorted(self._sorted, np.asarray(ids, np.int64))]

    def rows(self, groups) -> np.ndarray:
        """The rows of ``groups`` laid end to end in that order, each group's in its dict order."""
        n = self.count[groups]
        return np.arange(int(n.sum())) + np.repeat(self.start[groups] - (np.cumsum(n) - n), n)

    def of(self, ids):
        """(keyframes, keypoint rows, observations per landmark) of landmarks ``ids`` in that order:
        what chaining their ``obs`` dicts gives."""
        g = self.groups(ids)
        r = self.rows(g)
        return self.kf[r], self.kp[r], self.count[g]

    def drop_keyframe(self, k: int) -> None:
        """Keyframe ``k``'s observations left the landmarks (``keyframe_culling.cull_keyframe``)."""
        dead = self.kf == k
        if not dead.any():
            return
        group = np.repeat(np.arange(len(self.ids)), self.count)
        self.count = self.count - np.bincount(group[dead], minlength=len(self.ids))
        self.kf, self.kp = self.kf[~dead], self.kp[~dead]
        self.start = np.cumsum(self.count) - self.count


def local_map_update(index: int, keyframes: dict, landmarks: dict, local: list[int], fixed: list[int]):
    """The local map tracking needs after keyframe ``index``: the landmarks seen by the local and
    fixed keyframes (ids, positions, descriptors) and the refined poses of the local ones. Shared
    by the stereo and the monocular mapper (both keep ``keyframes[k].landmark`` / ``landmarks[id]``)."""
    from canopy.frontend.messages import LocalMapUpdate

    seen = [keyframes[k].landmark for k in list(local) + list(fixed)]
    ids = _sorted_unique_ids(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
    rows = getattr(landmarks, "rows", None)
    if rows is not None:   # a LandmarkStore: one gather per array (walking ~6 k landmarks cost ~3.5 ms per KITTI keyframe)
        pos, desc = rows.pos[ids], rows.desc[ids]
    else:
        lms = [landmarks[i] for i in ids.tolist()]
        # one concatenate of the small arrays (1.5x faster than np.array over a list of arrays)
        pos = np.concatenate([lm.position for lm in lms]).astype(float).reshape(-1, 3) if lms else np.zeros((0, 3))
        desc = np.concatenate([lm.descriptor for lm in lms]).reshape(-1, 32) if lms else np.zeros((0, 32), np.uint8)
    poses = {k: keyframes[k].T_world_cam.copy() for k in local}
    return LocalMapUpdate(index, ids, pos, desc.astype(np.uint8, copy=False), poses)


class MapStoreAccess:
    """What both mappers (stereo ``LocalMapper``, monocular ``MonoMapper``) answer from their
    ``keyframes`` / ``landmarks`` stores, written once."""

    keyframes: dict
    landmarks: dict

    def keyframe_trajectory(self):
        from shared.types import Trajectory

        culled = self._culled_poses()
        idx = sorted(set(self.keyframes) | set(culled))
        stamps = [self.keyframes[i].timestamp if i in self.keyframes else self.culled_keyframes[i][2] for i in idx]
        poses = [self.keyframes[i].T_world_cam if i in self.keyframes else culled[i] for i in idx] \
            if idx else np.zeros((0, 4, 4))
        return Trajectory(np.asarray(stamps, float), np.asarray(poses, float), meta={"indices": idx})

    def keyframe_poses(self) -> dict[int, np.ndarray]:
        """Every keyframe's pose, culled ones (mapping.keyframe_culling) too, through their parents: the
        frames tracked against a culled keyframe keep following the map's corrections."""
        poses = {i: k.T_world_cam.copy() for i, k in self.keyframes.items()}
        poses.update(self._culled_poses())
        return poses

    def _culled_poses(self) -> dict[int, np.ndarray]:
        culled = getattr(self, "culled_keyframes", None)
        if not culled:
            return {}
        from canopy.backend.keyframe_culling import culled_pose
        out = {k: culled_pose(self.keyframes, culled, k) for k in culled}
        return {k: T for k, T in out.items() if T is not None}

    def map_points(self) -> np.ndarray:
        if not self.landmarks:
            return np.zeros((0, 3))
        rows = getattr(self.landmarks, "rows", None)
        if rows is not None:   # dict order, as below, by one gather
            return rows.pos[np.fromiter(self.landmarks.keys(), np.int64, len(self.landmarks))]
        return np.array([lm.position for lm in self.landmarks.values()], float)

    def _add_seen_counts(self, kf) -> None:
        """ORB-SLAM's found / visible statistics tracking collected since the last keyframe
        (``KeyframeData.seen_*``) added to the landmarks still in the map."""
        for lid, vis, fnd in zip(kf.seen_ids.tolist(), kf.seen_visible.tolist(), kf.seen_found.tolist()):
            lm = self.landmarks.get(lid)
            if lm is not None:
                lm.visible += vis
                lm.found += fnd

    def _observation_edges(self, local: list[int], kf_set: set[int], table: ObservationTable | None = None):
        """Local BA's point edges: the landmarks the ``local`` keyframes observe (sorted ids) and
        every observation of them by a keyframe of ``kf_set``, as arrays (keyframe, landmark,
        keypoint row). ``table``: the step's observations where nothing changed them since it was
        read. Returns (lm_ids, e_kf, e_lm, e_kp)."""
        seen = [self.keyframes[k].landmark for k in local]
        lm_arr = _sorted_unique_ids(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
        lm_ids = lm_arr.tolist()
        # every landmark's observations in their dict order from the step's table (the window read
        # them already: LocalMapper._local_window) or chained here, then the window's by a lookup table
        if table is None:
            table = ObservationTable(self.landmarks, lm_arr)
        else:
            table.add(lm_arr)
        e_kf, e_kp, n_obs = table.of(lm_arr)
        total = len(e_kf)
        e_lm = np.repeat(lm_arr, n_obs)
        if total == 0 or not kf_set:
            keep = np.zeros(total, bool)
        else:
            in_set = np.zeros(max(int(e_kf.max()), max(kf_set)) + 1, bool)
            in_set[list(kf_set)] = True
            keep = in_set[e_kf]
        p = getattr(self, "params", None)
        if getattr(p, "window_max_fixed", 0) > 0 or getattr(p, "keyframe_culling", False):
            # BA sees part of the landmarks' observations: only depth-constrained ones move (still_window)
            from canopy.backend.still_window import depth_constrained
            return depth_constrained(self, lm_ids, e_kf[keep], e_lm[keep], e_kp[keep])
        return lm_ids, e_kf[keep], e_lm[keep], e_kp[keep]

    def _delete_landmark(self, lid: int) -> None:
        """Cull landmark ``lid``: out of the store and out of every keyframe that observed it."""
        lm = self.landmarks.pop(lid)
        for k, i in lm.obs.items():
            self.keyframes[k].landmark[i] = -1
        self.n_culled += 1

    def _remove_observation(self, lid: int, k: int) -> None:
        """Drop keyframe ``k``'s observation of landmark ``lid`` (both indices kept in step)."""
        lm = self.landmarks.get(lid)
        if lm is None or k not in lm.obs:
            return
        i = lm.obs.pop(k)
        self.keyframes[k].landmark[i] = -1
