"""New landmarks triangulated across keyframes in the stereo local mapper (issues 8, 9).

The stereo mapper makes a landmark from the keyframe's own stereo match only; a keypoint
whose right-image match was lost (haze: the right image's FAST fires on another subset of
faint far corners, docs/notes/s13-haze.md) or lies beyond the stereo's useful depth never
becomes a landmark. ORB-SLAM's LocalMapping::CreateNewMapPoints also matches the new
keyframe's keypoints without a map point against its covisible keyframes' free keypoints
(ORBmatcher::SearchForTriangulation: descriptor match inside the epipolar band) and
triangulates them: over a keyframe baseline of a metre or more a far point has real parallax.

The pair step is the monocular mapper's ``canopy.mono.triangulation.new_points_between``
(epipolar band, best-of-two Hamming, each keypoint once; parallax cos < 0.9998, depth > 0 in
both, 2-DoF reprojection chi-square in both, distance ratio following the octave ratio), shared
as is so the monocular mapper stays bit-identical. Here: which keyframe pairs, and the ids.

Landmark ids: tracking numbers its landmarks with a dense counter from 0 in another process,
so the mapper's own landmarks take ids from ``MappingParams.triangulate_id_base`` upwards (a
range tracking does not reach; ``check_tracker_ids`` says so clearly if it ever does).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.mono.triangulation import new_points_between
from shared.types import StereoCalibration


@dataclass(frozen=True)
class PairGates:
    """The gates ``new_points_between`` reads (the names of ``MonoParams``' fields)."""

    epipolar_chi2: float
    triangulation_max_hamming: int
    triangulation_ratio: float
    chi2_mono: float


def pair_gates(params) -> PairGates:
    """``PairGates`` from ``MappingParams`` (mapping.triangulate_*)."""
    return PairGates(params.triangulate_epipolar_chi2, params.triangulate_max_hamming,
                     params.triangulate_ratio, params.chi2_mono)


def triangulation_partners(rec, keyframes: dict, counts: dict[int, int], n_best: int,
                           min_baseline: float) -> list[int]:
    """The ``n_best`` keyframes sharing most landmarks with ``rec`` (``counts``: keyframe index ->
    shared landmarks) in ``rec``'s map segment whose centre is at least ``min_baseline`` m away
    (ORB-SLAM's stereo CreateNewMapPoints skips a pair whose baseline is below the rig's: the
    stereo pair itself measures such points better)."""
    cand = sorted((k for k in counts if k in keyframes and keyframes[k].segment == rec.segment),
                  key=lambda k: (-counts[k], -k))
    out = []
    c = rec.T_world_cam[:3, 3]
    for k in cand:
        if np.linalg.norm(keyframes[k].T_world_cam[:3, 3] - c) >= min_baseline:
            out.append(k)
            if len(out) >= n_best:
                break
    return out


def triangulate_with_partners(rec, keyframes: dict, partners: list[int], calib: StereoCalibration, gates: PairGates,
                              scale: float, pixel_sigma: float):
    """Match and triangulate ``rec``'s free keypoints with each partner's in turn (best partner
    first; a keypoint used by one pair is no longer free for the next, as in ORB-SLAM).
    Returns a list of (partner index, rows of rec, rows of partner, world points (K,3)); the
    ``landmark`` arrays are not changed (the caller assigns ids), free rows are tracked here."""
    taken = rec.landmark.copy()
    out = []
    for k in partners:
        b = keyframes[k]
        view = _FreeView(rec, taken)
        ka, kb, Pw = new_points_between(view, b, calib, gates, scale, pixel_sigma)
        if len(ka):
            taken[ka] = 0   # any id >= 0: used
            out.append((k, ka, kb, Pw))
    return out


class _FreeView:
    """``rec`` with another ``landmark`` array (the rows already triangulated marked used)."""

    __slots__ = ("T_world_cam", "uv", "octave", "descriptors", "landmark")

    def __init__(self, rec, landmark: np.ndarray):
        self.T_world_cam, self.uv, self.octave, self.descriptors = rec.T_world_cam, rec.uv, rec.octave, rec.descriptors
        self.landmark = landmark


def check_tracker_ids(new_ids: np.ndarray, base: int) -> None:
    """Tracking's landmark ids must stay below the mapper's own id range."""
    new_ids = np.asarray(new_ids)
    if len(new_ids) and int(new_ids.max()) >= base:
        raise ValueError(f"KeyframeData.new_landmark_ids reached {int(new_ids.max())}, inside the mapper's "
                         f"triangulated-landmark id range (mapping.triangulate_id_base = {base}): raise it")
