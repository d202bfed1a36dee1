"""Landmark observations in arrays (issue 8): ``ObservationStore`` keeps every stored landmark's
observations (keyframe index, keypoint row) in id-indexed rows, mirrored from the landmarks' dicts
(``ObsDict``); ``ObservationTable`` is the same reading from a snapshot of the dicts, for a
``LandmarkStore`` whose ids are too sparse for rows. ``observation_reader`` picks one.

Why: one keyframe's mapping steps read the observations of ~10^3 landmarks several times (the
distinctive descriptors and covisibility of the new keyframe's landmarks, the window's fixed set,
local BA's edges, keyframe culling's redundancy). Chaining the dicts (``np.fromiter`` over their
keys and values) cost ~40 ns an entry, ~3-6 ms per EuRoC keyframe; a row gather costs a few ns.
Every reader gets what chaining the dicts gives, in the dicts' (insertion) order: local BA sums its
edges in that order, and the distinctive descriptor breaks ties by it.
"""
from __future__ import annotations

from itertools import chain
from operator import attrgetter

import numpy as np

from shared.arrays import unique_sorted

_OBS = attrgetter("obs")


class ObsDict(dict):
    """A landmark's observations (keyframe index -> keypoint row): a plain dict to every reader,
    whose changes are mirrored in its ``LandmarkStore``'s ``ObservationStore`` while the landmark is
    stored there (``_store`` not None). The mapper's bulk changes (a keyframe's insertion, keyframe
    culling) write the dicts with ``dict``'s own methods and the store in one array operation; the
    hooks here keep every other change (BA's outliers, fusion, a loop's merge, a loaded map, a test)
    in step. Pickles and copies as a plain dict."""

    # set while stored (``LandmarkStore._observe``), unset or None otherwise; no Python-level __init__:
    # dict's own builds a new landmark's dict (an __init__ here cost ~0.4 us a landmark, ~0.3 ms per
    # KITTI keyframe's ~700 new ones)
    __slots__ = ("_store", "_lid")

    def __setitem__(self, k, i) -> None:
        dict.__setitem__(self, k, i)
        st = _store_of(self)
        if st is not None:
            st.set_one(self._lid, k, i)

    def __delitem__(self, k) -> None:
        dict.__delitem__(self, k)
        st = _store_of(self)
        if st is not None:
            st.remove_one(self._lid, k)

    def pop(self, k, *default):
        if k not in self:
            return dict.pop(self, k, *default)
        i = dict.pop(self, k)
        st = _store_of(self)
        if st is not None:
            st.remove_one(self._lid, k)
        return i

    def popitem(self):
        k, i = dict.popitem(self)
        st = _store_of(self)
        if st is not None:
            st.remove_one(self._lid, k)
        return k, i

    def clear(self) -> None:
        dict.clear(self)
        st = _store_of(self)
        if st is not None:
            st.load(np.array([self._lid], np.int64), [self])

    def update(self, *args, **kwargs) -> None:
        for k, i in dict(*args, **kwargs).items():
            self[k] = i

    def setdefault(self, k, i=None):
        if k not in self:
            self[k] = i
        return dict.__getitem__(self, k)

    def __ior__(self, other):
        self.update(other)
        return self

    def __reduce__(self):
        return dict, (dict(self),)


def _store_of(obs: ObsDict):
    """The store mirroring ``obs`` (None: not stored)."""
    return getattr(obs, "_store", None)


class ObservationStore:
    """Every stored landmark's observations in arrays (issue 8): row ``id`` holds the landmark's
    keyframe indices (``kf``) and keypoint rows (``kp``) in its dict's insertion order in its first
    ``n[id]`` columns. A keyframe's steps read the observations of ~10^3 landmarks several times
    (distinctive descriptors, covisibility, the window, BA's edges, keyframe culling); chaining the
    dicts cost ~10 ms per EuRoC hover keyframe, ~40 ns an entry. Here a read is one gather, and
    the dicts' changes come in bulk (``append``, ``drop_keyframe``) or one by one through ``ObsDict``.
    Rows are indexed by the landmark id as ``LandmarkRows`` (tracking's ids are a dense counter);
    ``LandmarkStore`` turns the store off for ids far beyond that. int32 columns: frame indices
    and keypoint rows stay far below 2^31."""

    def __init__(self):
        self.kf = np.zeros((0, 8), np.int32)
        self.kp = np.zeros((0, 8), np.int32)
        self.n = np.zeros(0, np.int64)

    def _reserve(self, top: int, width: int) -> None:
        rows, cols = self.kf.shape
        if top < rows and width <= cols:
            return
        R = max(top + 1, 2 * rows, 1024) if top >= rows else rows
        C = max(width, 2 * cols) if width > cols else cols
        kf, kp, n = np.zeros((R, C), np.int32), np.zeros((R, C), np.int32), np.zeros(R, np.int64)
        kf[:rows, :cols], kp[:rows, :cols], n[:rows] = self.kf, self.kp, self.n
        self.kf, self.kp, self.n = kf, kp, n

    def load(self, ids: np.ndarray, obs: list) -> None:
        """Rows ``ids`` (distinct) set to the dicts ``obs``."""
        if len(ids) == 0:
            return
        cnt = np.fromiter(map(len, obs), np.int64, len(obs))
        total = int(cnt.sum())
        self._reserve(int(ids.max()), int(cnt.max()))
        self.n[ids] = cnt
        rows = np.repeat(ids, cnt)
        cols = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        self.kf[rows, cols] = np.fromiter(chain.from_iterable(obs), np.int64, total)
        self.kp[rows, cols] = np.fromiter(chain.from_iterable(map(dict.values, obs)), np.int64, total)

    def append(self, ids: np.ndarray, k: int, kps: np.ndarray) -> None:
        """Keyframe ``k``'s observations ``kps`` of landmarks ``ids`` (distinct, new keys) added last."""
        if len(ids) == 0:
            return
        col = self.n[ids]
        self._reserve(int(ids.max()), int(col.max()) + 1)
        self.kf[ids, col] = k
        self.kp[ids, col] = kps
        self.n[ids] = col + 1

    def set_one(self, lid: int, k: int, i: int) -> None:
        c = int(self.n[lid])
        hit = np.flatnonzero(self.kf[lid, :c] == k)
        if len(hit):   # a dict keeps an overwritten key in place
            self.kp[lid, hit[0]] = i
            return
        self._reserve(lid, c + 1)
        self.kf[lid, c], self.kp[lid, c], self.n[lid] = k, i, c + 1

    def remove_one(self, lid: int, k: int) -> None:
        c = int(self.n[lid])
        hit = np.flatnonzero(self.kf[lid, :c] == k)
        if len(hit):
            j = int(hit[0])
            self.kf[lid, j:c - 1] = self.kf[lid, j + 1:c].copy()
            self.kp[lid, j:c - 1] = self.kp[lid, j + 1:c].copy()
            self.n[lid] = c - 1

    def drop_keyframe(self, k: int, ids) -> None:
        """Keyframe ``k``'s observations left landmarks ``ids`` (the others keep their order)."""
        ids = np.asarray(ids, np.int64)
        if len(ids) == 0:
            return
        c = self.n[ids]
        m = int(c.max())
        sub_kf, sub_kp = np.take(self.kf, ids, axis=0)[:, :m], np.take(self.kp, ids, axis=0)[:, :m]
        hit = (sub_kf == k) & (np.arange(m) < c[:, None])
        rows = np.flatnonzero(hit.any(axis=1))
        if len(rows) == 0:
            return
        # the hit column moved last by a stable sort of the hit flags: the others keep their order
        order = np.argsort(hit[rows], axis=1, kind="stable")
        lids = ids[rows]
        self.kf[lids, :m] = np.take_along_axis(sub_kf[rows], order, axis=1)
        self.kp[lids, :m] = np.take_along_axis(sub_kp[rows], order, axis=1)
        self.n[lids] -= 1

    def add(self, ids) -> None:
        """Always current: nothing to read (the ``ObservationTable`` interface)."""

    def of(self, ids):
        """(keyframes, keypoint rows, observations per landmark) of landmarks ``ids`` (any order,
        repeats allowed) in that order: what chaining their ``obs`` dicts gives."""
        ids = np.asarray(ids, np.int64)
        n = self.n[ids]
        m = int(n.max()) if len(n) else 0
        keep = np.arange(m) < n[:, None]
        # whole rows by np.take (~5x cheaper than a fancy index of 2-D rows), then the first n of each
        return (np.take(self.kf, ids, axis=0)[:, :m][keep].astype(np.int64),
                np.take(self.kp, ids, axis=0)[:, :m][keep].astype(np.int64), n)


class ObservationTable:
    """The observations of a set of landmarks read from their dicts once (keys and values chained at
    C level), for a store without an ``ObservationStore`` (sparse ids) or a plain dict of landmarks
    (the monocular mapper): the same readers (``of``) over a snapshot. Each landmark's rows are
    contiguous and in its dict's order; landmarks are added as readers need them (``add``).

    A snapshot: whoever changes observations while it is in use says so (``drop_keyframe``, keyframe
    culling) or reads a new one. ``LocalMapper.insert_keyframe`` uses one from insertion to local BA's
    edges (nothing changes observations in between) and one for keyframe culling."""

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

    def drop_keyframe(self, k: int, ids=None) -> None:
        """Keyframe ``k``'s observations left the landmarks (``keyframe_culling.cull_keyframe``;
        ``ids``, the landmarks it left, is for ``ObservationStore``'s signature)."""
        dead = self.kf == k
        if not dead.any():
            return
        group = np.repeat(np.arange(len(self.ids)), self.count)
        self.count = self.count - np.bincount(group[dead], minlength=len(self.ids))
        self.kf, self.kp = self.kf[~dead], self.kp[~dead]
        self.start = np.cumsum(self.count) - self.count


def observation_reader(landmarks, ids=(), table: ObservationTable | None = None):
    """Where to read the current observations of landmarks ``ids``: the store's ``ObservationStore``
    (always current), else ``table`` (a snapshot still current; ``ids`` added) or a new table."""
    st = getattr(landmarks, "observations", None)
    if st is not None:
        return st
    if table is None:
        return ObservationTable(landmarks, ids)
    table.add(ids)
    return table
