"""Keyframe culling (ORB-SLAM LocalMapping::KeyFrameCulling; Mur-Artal & Tardos 2017, §V-E of the
ORB-SLAM2 paper: "discard all the keyframes in the local map whose 90 % of the map points have been
seen in at least other three keyframes").

Why here: on a still camera with a frequent keyframe cadence (configs/euroc.yaml's 3-frame cap,
docs/notes/s14-jitter.md) every new keyframe observes the landmarks the earlier ones saw, so local
BA's fixed set (every keyframe observing a local landmark) and the distinctive-descriptor update
(O(n^2) in a landmark's observations) grow with every keyframe: local mapping's CPU per keyframe
rose 17 -> 42 -> 94 ms over the EuRoC snippet's thirds (docs/notes/s15-stillcost.md). Dropping the
keyframes whose landmarks others already see bounds both.

What culling a keyframe means for the rest of the system:
* its observations leave its landmarks (a landmark no other keyframe sees goes with it, as the
  mapper's ``_cull`` would drop it at the next keyframe anyway);
* its pose stays available read-only, relative to a parent keyframe (ORB-SLAM keeps a culled
  keyframe's ``mTcp`` to its spanning-tree parent): ``MapStoreAccess.keyframe_poses`` /
  ``keyframe_trajectory`` return it, so the frames that tracked against it (trajectory.tum,
  frames.csv, the lockstep pipelines' final poses are ``T_world_ref @ T_ref_cam``) still follow
  local BA's and the loop closer's corrections of the map;
* the new keyframe (tracking's reference) and each map segment's first keyframe (the gauge
  local BA holds fixed) are never culled, nor the newest ``keyframe_culling_keep_recent`` ones,
  nor the two keyframes of a closed loop (``LocalMapper.loop_keyframes``, ORB-SLAM's SetNotErase:
  the loop closer's pose graph holds an edge between them);
* the loop closer keeps its own copy of every keyframe it was sent (canopy.loop.detector), so its
  database and pose graph never ask the mapper for a culled one; corrections reach the mapper's
  remaining keyframes and, through the parents, the culled ones.
"""
from __future__ import annotations

import numpy as np

from canopy.backend.observations import ObservationTable, observation_reader


def redundant_fraction(mapper, k: int, min_observers: int, table: ObservationTable | None = None) -> float:
    """Share of keyframe ``k``'s landmarks that at least ``min_observers`` other keyframes observe at
    the same or a finer scale (octave <= k's octave + 1, ORB-SLAM's ``scaleLeveli <= scaleLevel+1``).
    0 for a keyframe without landmarks. Every observation of k's landmarks comes as arrays from
    ``table`` (``map_store.ObservationTable``: current observations; k's landmarks are added to it)
    or one read here: no Python step per observation."""
    rec = mapper.keyframes[k]
    rows = np.flatnonzero(rec.landmark >= 0)
    if len(rows) == 0:
        return 0.0
    lids = rec.landmark[rows]
    e_kf, e_kp, n_obs = observation_reader(mapper.landmarks, lids, table).of(lids)
    # every observing keyframe's octaves laid end to end, found by an offset table
    kf_ids = np.unique(e_kf)
    table = np.concatenate([mapper.keyframes[kk].octave for kk in kf_ids.tolist()])
    start = np.zeros(int(kf_ids[-1]) + 1, np.int64)
    start[kf_ids] = np.cumsum([0] + [len(mapper.keyframes[kk].octave) for kk in kf_ids[:-1].tolist()])
    limit = np.repeat(rec.octave[rows] + 1, n_obs)
    counts = (e_kf != k) & (table[start[e_kf] + e_kp] <= limit)
    per_landmark = np.add.reduceat(counts.astype(np.int64), np.cumsum(n_obs) - n_obs)
    return float(np.count_nonzero(per_landmark >= min_observers)) / len(rows)


def cull_keyframe(mapper, k: int, table: ObservationTable | None = None) -> int:
    """Remove keyframe ``k`` from the map: its observations leave its landmarks (landmarks left
    without any are deleted), and its pose is kept relative to the remaining keyframe it shares the
    most landmarks with (``mapper.culled_keyframes[k] = (parent, T_parent_k, timestamp)``). Returns the
    parent. ``table``: current observations (``map_store.ObservationTable``), kept current here."""
    rec = mapper.keyframes[k]
    lids = [lid for lid in rec.landmark[rec.landmark >= 0].tolist() if lid in mapper.landmarks]
    # the other observers of its landmarks counted by np.bincount (a generator per landmark cost ~5 ms
    # per culled EuRoC keyframe, ~600 landmarks x ~20 observers); k's own count is dropped after
    table = observation_reader(mapper.landmarks, lids, table)
    per_kf = np.bincount(table.of(lids)[0]) if lids else np.zeros(0, np.int64)
    seen = np.flatnonzero(per_kf)
    shared = dict(zip(seen.tolist(), per_kf[seen].tolist()))
    shared.pop(k, None)
    same = [kk for kk in shared if mapper.keyframes[kk].segment == rec.segment]
    if same:
        parent = max(same, key=lambda kk: (shared[kk], kk))
    else:  # no landmark shared: the nearest older keyframe of the segment (there is one: the first is never culled)
        parent = max(kk for kk, r in mapper.keyframes.items() if kk < k and r.segment == rec.segment)
    T_parent = mapper.keyframes[parent].T_world_cam
    mapper.culled_keyframes[k] = (parent, np.linalg.inv(T_parent) @ rec.T_world_cam, rec.timestamp)
    # k leaves its landmarks' dicts by dict's own pop and the observation arrays in one step (ObsDict's
    # hook per observation cost ~1 us each)
    dropped = []
    for lid in lids:
        lm = mapper.landmarks.get(lid)
        if lm is None:
            continue
        obs = lm._obs   # the dict by its slot (the property costs ~0.12 us a read)
        if dict.pop(obs, k, None) is not None:
            dropped.append(lid)
        if not obs:
            del mapper.landmarks[lid]
            mapper.n_culled += 1
    table.drop_keyframe(k, dropped)
    if rec.line_landmark is not None:
        for lid in rec.line_landmark[rec.line_landmark >= 0].tolist():
            ln = mapper.lines.get(lid)
            if ln is not None:
                ln.obs.pop(k, None)
    del mapper.keyframes[k]
    getattr(mapper, "_no_triangulation", {}).pop(k, None)
    mapper.n_keyframes_culled += 1
    return parent


def cull_redundant_keyframes(mapper, rec, covisible: dict[int, int], table: ObservationTable | None = None) -> list[int]:
    """ORB-SLAM's KeyFrameCulling after keyframe ``rec``: each of its covisible keyframes (strongest
    first, as GetVectorCovisibleKeyFrames) whose landmarks are more than ``keyframe_culling_redundancy``
    (ORB-SLAM: nRedundantObservations > 0.9 nMPs) seen by ``keyframe_culling_observers`` other keyframes goes, in turn (a culled keyframe's
    observations no longer count for the next). Protected: ``rec``, its segment's first keyframe, and
    the newest ``keyframe_culling_keep_recent`` keyframes, and the keyframes of a closed loop
    (``mapper.loop_keyframes``). ``table``: current observations (``map_store.ObservationTable``) shared
    by the candidates' tests and kept current by each culling. Returns the culled keyframes' indices."""
    p = mapper.params
    table = observation_reader(mapper.landmarks, (), table)
    first = mapper._segment_first[rec.segment]
    loop = getattr(mapper, "loop_keyframes", ())
    recent = {r.index for r in sorted(mapper.keyframes.values(), key=lambda r: r.order)[-p.keyframe_culling_keep_recent:]} \
        if p.keyframe_culling_keep_recent > 0 else set()
    culled = []
    for k in sorted(covisible, key=lambda kk: (-covisible[kk], -kk)):
        if k == rec.index or k == first or k in recent or k in loop or k not in mapper.keyframes \
                or mapper.keyframes[k].segment != rec.segment:
            continue
        if redundant_fraction(mapper, k, p.keyframe_culling_observers, table) > p.keyframe_culling_redundancy:
            cull_keyframe(mapper, k, table)
            culled.append(k)
    return culled


def culled_pose(keyframes: dict, culled: dict, k: int) -> np.ndarray | None:
    """World pose of culled keyframe ``k`` through its chain of parents (a parent may have been culled
    after it); None when the chain ends at no keyframe."""
    T = np.eye(4)
    seen = set()
    while k not in keyframes:
        if k not in culled or k in seen:
            return None
        seen.add(k)
        parent, T_pk = culled[k][:2]
        T = T_pk @ T
        k = parent
    return keyframes[k].T_world_cam @ T
