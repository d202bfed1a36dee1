"""What place recognition keeps of a keyframe (or of a frame being relocalised).

Only what loop closing needs crosses to it (pySLAM's ``LoopDetectKeyframeData`` idea):
keypoints with their stereo match, descriptors, the landmark each keypoint observes, the
pose, and the bag-of-words vector. ``describe_stereo_pair`` builds one straight from a
rectified stereo pair with the tracking front end's ORB and stereo matching, for
relocalisation and for tests on real image pairs.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.loop.database import Bow, FeatureStats
from shared.types import StereoCalibration


@dataclass
class PlaceKeyframe:
    index: int
    timestamp: float
    T_world_cam: np.ndarray       # (4,4)
    uv: np.ndarray                # (N,2) left keypoints, px
    u_right: np.ndarray           # (N,) right-image u, -1 where no stereo match
    depth: np.ndarray             # (N,) m, -1 where no stereo match
    octave: np.ndarray            # (N,)
    descriptors: np.ndarray       # (N,32) uint8
    landmark_ids: np.ndarray      # (N,) int64, -1 where the keypoint observes no landmark
    bow: Bow = field(default_factory=dict)
    word_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (N,) vocabulary word per keypoint
    line_bow: Bow = field(default_factory=dict)
    stats: FeatureStats = field(default_factory=FeatureStats)
    # (N,3) world position of the landmark each keypoint observes (NaN: none), as local
    # mapping has it when it sends the keyframe: the starting point of the full BA
    landmark_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def __len__(self) -> int:
        return len(self.uv)

    @property
    def has_depth(self) -> np.ndarray:
        return np.asarray(self.depth) > 0

    def points_cam(self, calib: StereoCalibration) -> np.ndarray:
        """(N,3) back-projected stereo points in this camera's frame (NaN where no depth)."""
        z = np.where(self.has_depth, np.asarray(self.depth, float), np.nan)
        u, v = np.asarray(self.uv, float).T
        return np.stack([(u - calib.cx) * z / calib.fx, (v - calib.cy) * z / calib.fy, z], axis=1)


def with_bow(kf: PlaceKeyframe, vocabulary) -> PlaceKeyframe:
    """Fill ``bow`` and ``word_ids`` from the vocabulary (``transform(descriptors)``)."""
    if vocabulary is not None and len(kf.descriptors):
        bow, words = vocabulary.transform(np.ascontiguousarray(kf.descriptors, np.uint8))
        kf.bow = {int(w): float(v) for w, v in dict(bow).items()}
        kf.word_ids = np.asarray(words, np.int64).reshape(-1)
    kf.stats = FeatureStats(n_points=len(kf), n_lines=kf.stats.n_lines, spread_points=FeatureStats.of(kf.uv).spread_points,
                            spread_lines=kf.stats.spread_lines)
    return kf


def describe_stereo_pair(index: int, timestamp: float, left: np.ndarray, right: np.ndarray,
                         calib: StereoCalibration, tracking_params=None, vocabulary=None,
                         T_world_cam: np.ndarray | None = None) -> PlaceKeyframe:
    """ORB on both rectified images + stereo matching (AGRI §3.2.1-3.2.2), as tracking does."""
    from canopy.frontend import OrbExtractor, TrackingParams, match_stereo

    params = tracking_params or TrackingParams()
    extractor = OrbExtractor(params)
    fl, fr = extractor.extract(left), extractor.extract(right)
    stereo = match_stereo(fl, fr, left, right, calib, params)
    kf = PlaceKeyframe(index=index, timestamp=timestamp,
                       T_world_cam=np.eye(4) if T_world_cam is None else np.asarray(T_world_cam, float),
                       uv=fl.uv.astype(np.float64), u_right=stereo.u_right.astype(np.float64),
                       depth=stereo.depth.astype(np.float64), octave=fl.octave.astype(np.int64),
                       descriptors=fl.descriptors, landmark_ids=np.full(len(fl), -1, np.int64))
    return with_bow(kf, vocabulary)
