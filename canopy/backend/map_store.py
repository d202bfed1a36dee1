"""The map's records (the keyframe and landmark stores of ``LocalMapper``).

``LocalMapper.keyframes: dict[int, Keyframe]`` (by frame index), ``LocalMapper.landmarks:
dict[int, Landmark]`` and ``LocalMapper.lines: dict[int, LineLandmark]`` (by id) are the
whole map. A landmark's ``obs`` maps keyframe index -> keypoint row and the keyframe's
``landmark`` array is the reverse index; both are kept in step by every change.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from operator import attrgetter

import numpy as np

from canopy.backend.observations import ObsDict, ObservationStore, ObservationTable, observation_reader
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

    __slots__ = ("id", "_obs", "first_order", "segment", "visible", "found", "_rows", "_position", "_descriptor")

    def __init__(self, id: int, position, descriptor, obs: dict[int, int] | None = None, first_order: int = 0,
                 segment: int = 0, visible: int = 1, found: int = 1):
        self.id = id
        self._obs = ObsDict() if obs is None else ObsDict(obs)
        self.first_order = first_order
        self.segment = segment
        self.visible = visible
        self.found = found
        self._rows = None
        self._position = position
        self._descriptor = descriptor

    @property
    def obs(self) -> "ObsDict":
        """Keyframe index -> keypoint row, in insertion order (a dict; in a ``LandmarkStore`` its
        changes are mirrored in the store's ``ObservationStore``)."""
        return self._obs

    @obs.setter
    def obs(self, value) -> None:
        old, new = self._obs, ObsDict(value)
        store, lid = getattr(old, "_store", None), getattr(old, "_lid", -1)
        old._store = None
        self._obs = new
        if store is not None:
            new._store, new._lid = store, lid
            store.load(np.array([lid], np.int64), [new])

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
        state = {k: getattr(self, k) for k in ("id", "first_order", "segment", "visible", "found", "position",
                                                "descriptor")}
        state["obs"] = dict(self._obs)
        return state

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
        # every landmark's observations in arrays (None: off, readers chain the dicts: ObservationTable)
        self.observations: ObservationStore | None = ObservationStore()

    def __setitem__(self, lid, lm) -> None:
        if self.rows is not None and (lid != lm.id or lid < 0 or lid > _SPARSE * (len(self) + 1) + (1 << 20)):
            for other in self.values():
                other._attach(None)
            self.rows = None
        if self.rows is not None:
            self.rows.reserve(lid)
        lm._attach(self.rows)
        self._observe([lid], [lm])
        old = dict.get(self, lid)
        if old is not None and old is not lm:
            old._obs._store = None
        super().__setitem__(lid, lm)

    def _observe(self, ids: list, landmarks: list) -> None:
        """Mirror the landmarks' observations in ``observations`` (turned off for good by an id beyond
        the dense range: ``_DENSE_OBS``)."""
        st = self.observations
        if st is None or not ids:
            return
        top = max(ids)
        # off as well past the memory budget: rows span every id ever made (culled ones too) and are as
        # wide as the most-observed landmark, so a long run with long-lived landmarks would grow them
        # without bound; the dicts (ObservationTable) read the same values, only slower
        if (min(ids) < 0 or top > _DENSE_OBS * (len(self) + len(ids) + 1) + 4096
                or st.kf.nbytes + st.kp.nbytes > OBSERVATION_STORE_MAX_BYTES):
            for lm in self.values():
                lm._obs._store = None
            self.observations = None
            return
        obs = list(map(_OBS, landmarks))
        for o, lid in zip(obs, ids):   # a landmark lives in one store (as its LandmarkRows)
            o._store = st
            o._lid = lid
        st.load(np.asarray(ids, np.int64), obs)

    def _forget(self, lm) -> None:
        if lm is not None:
            lm._obs._store = None

    def pop(self, lid, *default):
        lm = dict.pop(self, lid, *default)
        if lm is not None and lm is not (default[0] if default else None):
            self._forget(lm)
        return lm

    def __delitem__(self, lid) -> None:
        self._forget(dict.get(self, lid))
        dict.__delitem__(self, lid)

    def popitem(self):
        lid, lm = dict.popitem(self)
        self._forget(lm)
        return lid, lm

    def clear(self) -> None:
        for lm in self.values():
            self._forget(lm)
        dict.clear(self)

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
        lids = ids.tolist()
        self._observe(lids, landmarks)
        dict.update(self, zip(lids, landmarks))

    def update(self, *args, **kwargs) -> None:
        for lid, lm in dict(*args, **kwargs).items():
            self[lid] = lm

    def setdefault(self, lid, lm=None):
        if lid not in self:
            self[lid] = lm
        return self[lid]


_SPARSE = 64
# ObservationStore's arrays past this many bytes: off for good (checked as each keyframe's landmarks are
# stored; one doubling may pass it before that). KITTI snippet 4.3 MB, EuRoC hover ~6 MB.
OBSERVATION_STORE_MAX_BYTES = 256 << 20
_DENSE_OBS = 64   # ObservationStore: ids up to 64 rows per stored landmark (triangulated ids from 1 << 20: off)
_ID = attrgetter("id")
_OBS = attrgetter("_obs")   # a Landmark's dict by its slot (Landmark.obs is a property)


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


def local_map_update(index: int, keyframes: dict, landmarks: dict, local: list[int], fixed: list[int]):
    """The local map tracking needs after keyframe ``index``: the landmarks seen by the local and
    fixed keyframes (ids, positions, descriptors) and the refined poses of the local ones. Shared
    by the stereo and the monocular mapper (both keep ``keyframes[k].landmark`` / ``landmarks[id]``)."""
    from canopy.frontend.messages import LocalMapUpdate

    seen = [keyframes[k].landmark for k in list(local) + list(fixed)]
    ids = _sorted_unique_ids(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
    rows = getattr(landmarks, "rows", None)
    if rows is not None:   # a LandmarkStore: one gather per array (walking ~6 k landmarks cost ~3.5 ms per KITTI keyframe)
        pos, desc = np.take(rows.pos, ids, axis=0), np.take(rows.desc, ids, axis=0)   # np.take: ~5x a fancy index
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
        keypoint row). ``table``: a snapshot of the observations still current, where the store keeps
        none (``observations.observation_reader``). Returns (lm_ids, e_kf, e_lm, e_kp)."""
        seen = [self.keyframes[k].landmark for k in local]
        lm_arr = _sorted_unique_ids(np.concatenate(seen)) if seen else np.zeros(0, np.int64)
        lm_ids = lm_arr.tolist()
        # every landmark's observations in their dict order by one gather (observations.py), then the
        # window's by a lookup table (a generator over ~7 k edges cost ~3 ms per KITTI keyframe)
        e_kf, e_kp, n_obs = observation_reader(self.landmarks, lm_arr, table).of(lm_arr)
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
