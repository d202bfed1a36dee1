"""Maps that outlive a run: local mapping's map as one versioned msgpack file.

The file holds what relocalising and extending a map need: keyframes (pose, keypoints with
stereo, descriptors, the landmark each keypoint observes), landmarks (position, descriptor),
covisibility (shared-landmark counts), the keyframes of closed loops (never culled, ORB-SLAM's
SetNotErase; optional: older files without it load with none), the calibration it was built with and the id of the
vocabulary its place recognition used. Arrays are stored as raw bytes with dtype and shape.
A file of another format version, or built with another calibration, is refused with an
error that says which.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import msgpack
import numpy as np

from shared.errors import InputError
from shared.types import StereoCalibration

MAP_FORMAT = "canopy-map"
MAP_VERSION = 1
CALIBRATION_TOLERANCE = 1e-6  # relative, per intrinsic


def _pack_array(a: np.ndarray) -> dict:
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}


def _unpack_array(d: dict, path: Path, name: str) -> np.ndarray:
    try:
        dtype = np.dtype(d["dtype"])
        shape = tuple(int(s) for s in d["shape"])
        return np.frombuffer(d["data"], dtype=dtype).reshape(shape).copy()
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(path, f"map field {name!r} is not a valid array ({exc})") from None


@dataclass
class MapData:
    calibration: StereoCalibration
    vocabulary: str
    kf_index: np.ndarray        # (K,) int64
    kf_timestamp: np.ndarray    # (K,)
    kf_pose: np.ndarray         # (K,4,4) T_world_cam
    kf_segment: np.ndarray      # (K,) int64
    kf_offsets: np.ndarray      # (K+1,) rows of keyframe k: offsets[k]:offsets[k+1]
    uv: np.ndarray              # (R,2)
    u_right: np.ndarray         # (R,)
    octave: np.ndarray          # (R,)
    descriptors: np.ndarray     # (R,32) uint8
    landmark: np.ndarray        # (R,) int64, -1: none
    lm_id: np.ndarray           # (M,) int64
    lm_position: np.ndarray     # (M,3)
    lm_descriptor: np.ndarray   # (M,32) uint8
    lm_segment: np.ndarray      # (M,) int64
    covisibility: np.ndarray    # (P,3) int64: keyframe a, keyframe b, shared landmarks
    # keyframes of closed loops (LocalMapper.loop_keyframes): a run extending the map must not cull them
    loop_keyframes: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    OPTIONAL_ARRAYS = ("loop_keyframes",)   # written always, read when present (files of s16 and before lack it)
    ARRAYS = ("kf_index", "kf_timestamp", "kf_pose", "kf_segment", "kf_offsets", "uv", "u_right", "octave",
              "descriptors", "landmark", "lm_id", "lm_position", "lm_descriptor", "lm_segment", "covisibility")

    def keyframe_rows(self, k: int) -> slice:
        return slice(int(self.kf_offsets[k]), int(self.kf_offsets[k + 1]))


def map_from_mapper(mapper, vocabulary: str = "") -> MapData:
    """Snapshot of a ``LocalMapper`` (keyframes, landmarks and their covisibility)."""
    idx = sorted(mapper.keyframes)
    kfs = [mapper.keyframes[i] for i in idx]
    counts = np.array([len(k.uv) for k in kfs], np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)

    def cat(get, shape, dtype):
        parts = [np.asarray(get(k), dtype).reshape(shape) for k in kfs]
        return np.concatenate(parts) if parts else np.zeros((0,) + shape[1:], dtype)

    lids = sorted(mapper.landmarks)
    lms = [mapper.landmarks[i] for i in lids]
    pairs: dict[tuple[int, int], int] = {}
    for lm in lms:
        obs = sorted(lm.obs)
        for a_i, a in enumerate(obs):
            for b in obs[a_i + 1:]:
                pairs[(a, b)] = pairs.get((a, b), 0) + 1
    cov = np.array([[a, b, n] for (a, b), n in sorted(pairs.items())], np.int64).reshape(-1, 3)
    return MapData(
        calibration=mapper.calib, vocabulary=vocabulary,
        kf_index=np.array(idx, np.int64), kf_timestamp=np.array([k.timestamp for k in kfs], float),
        kf_pose=np.array([k.T_world_cam for k in kfs], float).reshape(-1, 4, 4),
        kf_segment=np.array([k.segment for k in kfs], np.int64), kf_offsets=offsets,
        uv=cat(lambda k: k.uv, (-1, 2), np.float64), u_right=cat(lambda k: k.u_right, (-1,), np.float64),
        octave=cat(lambda k: k.octave, (-1,), np.int64), descriptors=cat(lambda k: k.descriptors, (-1, 32), np.uint8),
        landmark=cat(lambda k: k.landmark, (-1,), np.int64),
        lm_id=np.array(lids, np.int64), lm_position=np.array([lm.position for lm in lms], float).reshape(-1, 3),
        lm_descriptor=np.array([lm.descriptor for lm in lms], np.uint8).reshape(-1, 32),
        lm_segment=np.array([lm.segment for lm in lms], np.int64), covisibility=cov,
        loop_keyframes=np.array(sorted(set(getattr(mapper, "loop_keyframes", ())) & set(idx)), np.int64))


def save_map(path: str | Path, data: MapData) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": MAP_FORMAT, "version": MAP_VERSION, "calibration": data.calibration.to_dict(),
           "vocabulary": data.vocabulary, "arrays": {n: _pack_array(getattr(data, n)) for n in MapData.ARRAYS + MapData.OPTIONAL_ARRAYS}}
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(msgpack.packb(doc, use_bin_type=True))
    tmp.replace(path)  # never a half-written map under the final name
    return path


def _check_calibration(path: Path, stored: dict, calib: StereoCalibration) -> None:
    mine = calib.to_dict()
    for key, value in mine.items():
        theirs = stored.get(key)
        if theirs is None or abs(float(theirs) - float(value)) > CALIBRATION_TOLERANCE * max(1.0, abs(float(value))):
            raise InputError(path, f"map was built with another calibration ({key} = {theirs}, this camera has "
                                   f"{value}); it cannot be used with this sequence")


def load_map(path: str | Path, calib: StereoCalibration | None = None) -> MapData:
    """Read a map file; with ``calib``, refuse a map built with another calibration."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "map file not found")
    try:
        doc = msgpack.unpackb(path.read_bytes(), raw=False)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise InputError(path, f"not a Canopy map file ({type(exc).__name__})") from None
    if not isinstance(doc, dict) or doc.get("format") != MAP_FORMAT:
        raise InputError(path, "not a Canopy map file (no 'canopy-map' header)")
    if doc.get("version") != MAP_VERSION:
        raise InputError(path, f"map format version {doc.get('version')} is not supported by this build "
                               f"(reads version {MAP_VERSION})")
    stored = doc.get("calibration") or {}
    if calib is not None:
        _check_calibration(path, stored, calib)
    arrays = doc.get("arrays") or {}
    missing = [n for n in MapData.ARRAYS if n not in arrays]
    if missing:
        raise InputError(path, f"map file lacks {missing}")
    try:
        cal = StereoCalibration(**{k: (int(v) if k in ("width", "height") else float(v)) for k, v in stored.items()})
    except TypeError as exc:
        raise InputError(path, f"map calibration is incomplete ({exc})") from None
    data = MapData(calibration=cal, vocabulary=str(doc.get("vocabulary", "")),
                   **{n: _unpack_array(arrays[n], path, n) for n in MapData.ARRAYS + MapData.OPTIONAL_ARRAYS
                      if n in arrays})
    if len(data.kf_offsets) != len(data.kf_index) + 1 or int(data.kf_offsets[-1]) != len(data.uv):
        raise InputError(path, "map keyframe table is inconsistent with its keypoints")
    if not np.isin(data.loop_keyframes, data.kf_index).all():
        raise InputError(path, "map names loop keyframes it does not hold")
    return data


def restore_mapper(data: MapData, mapper) -> None:
    """Fill an empty ``LocalMapper`` with a loaded map (observations rebuilt from the keyframes)."""
    from canopy.backend.map_store import Keyframe, Landmark

    mapper.keyframes.clear()
    mapper.landmarks.clear()
    for j, lid in enumerate(data.lm_id.tolist()):
        mapper.landmarks[lid] = Landmark(lid, data.lm_position[j].copy(), data.lm_descriptor[j].copy(), {},
                                         segment=int(data.lm_segment[j]))
    for k, index in enumerate(data.kf_index.tolist()):
        rows = data.keyframe_rows(k)
        rec = Keyframe(index, float(data.kf_timestamp[k]), data.kf_pose[k].copy(), data.uv[rows].copy(),
                       data.u_right[rows].copy(), data.octave[rows].copy(), data.descriptors[rows].copy(),
                       data.landmark[rows].copy(), int(data.kf_segment[k]), k)
        mapper.keyframes[index] = rec
        for i in np.flatnonzero(rec.landmark >= 0).tolist():
            lm = mapper.landmarks.get(int(rec.landmark[i]))
            if lm is not None:
                lm.obs[index] = i
    if hasattr(mapper, "loop_keyframes"):   # the loop's keyframes stay protected from culling
        mapper.loop_keyframes = set(data.loop_keyframes.tolist())
    mapper._order = len(data.kf_index)
    mapper._segment = int(data.kf_segment.max()) if len(data.kf_segment) else -1
    # each segment's first keyframe holds the gauge in local BA (LocalMapper._local_window)
    mapper._segment_first = {}
    for index, segment in zip(data.kf_index.tolist(), data.kf_segment.tolist()):
        mapper._segment_first.setdefault(int(segment), int(index))


def first_free_index(data: MapData) -> int:
    """The first frame number a run extending this map can use: its keyframes are numbered by
    frame, so the extending run's frames continue after the loaded keyframes (ids never collide
    and sorted ids stay in time order, which the pose graph's odometry chain relies on)."""
    return int(data.kf_index.max()) + 1 if len(data.kf_index) else 0


def map_place_keyframes(data: MapData) -> list:
    """The map's keyframes as place recognition keeps them (``PlaceKeyframe``, no bag of words
    yet): stereo depth from the saved right-image u, landmark positions per keypoint."""
    from canopy.loop.keyframe import PlaceKeyframe

    cal = data.calibration
    disparity = data.uv[:, 0] - data.u_right
    good = (data.u_right >= 0) & (disparity > 1e-6)
    depth = np.full(len(data.uv), -1.0)
    depth[good] = cal.fx * cal.baseline / disparity[good]
    order = np.argsort(data.lm_id)
    sorted_ids = data.lm_id[order]
    out = []
    for k, index in enumerate(data.kf_index.tolist()):
        rows = data.keyframe_rows(k)
        lids = data.landmark[rows]
        j = np.clip(np.searchsorted(sorted_ids, lids), 0, max(len(sorted_ids) - 1, 0))
        known = (lids >= 0) & (sorted_ids[j] == lids) if len(sorted_ids) else np.zeros(len(lids), bool)
        P = np.full((len(lids), 3), np.nan)
        P[known] = data.lm_position[order[j[known]]]
        out.append(PlaceKeyframe(index=int(index), timestamp=float(data.kf_timestamp[k]),
                                 T_world_cam=data.kf_pose[k].copy(), uv=data.uv[rows].copy(),
                                 u_right=np.where(good[rows], data.u_right[rows], -1.0), depth=depth[rows],
                                 octave=data.octave[rows].copy(), descriptors=data.descriptors[rows].copy(),
                                 landmark_ids=np.where(known, lids, -1), landmark_positions=P))
    return out


def seed_loop_closer(closer, data: MapData) -> int:
    """Give a ``LoopCloser`` the loaded map (``--load-map`` without ``--localize``): its keyframes
    go into the database and the pose graph, its landmarks into the closer's copy of the map, so
    that new keyframes can close loops against them. Returns the number of keyframes added."""
    from canopy.loop.keyframe import with_bow

    kfs = map_place_keyframes(data)
    for kf in kfs:
        closer.add_known_keyframe(with_bow(kf, closer.vocabulary))
    return len(kfs)
