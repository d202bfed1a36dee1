"""New landmarks triangulated across keyframes in the stereo local mapper (issues 8, 9).

The stereo mapper makes a landmark from the keyframe's own stereo match only; a keypoint
whose right-image match was lost (haze: the right image's FAST fires on another subset of
faint far corners, docs/notes/s13-haze.md) or lies beyond the stereo's useful depth never
becomes a landmark. ORB-SLAM's LocalMapping::CreateNewMapPoints also matches the new
keyframe's keypoints without a map point against its covisible keyframes' free keypoints
(ORBmatcher::SearchForTriangulation: descriptor match inside the epipolar band) and
triangulates them: over a keyframe baseline of a metre or more a far point has real parallax.

The pair step (``match_pair``) is the monocular mapper's
``canopy.mono.triangulation.new_points_between`` gate for gate (epipolar band, best of two by
Hamming within it, keypoints next to the epipole skipped, each keypoint once; then its
``checked_points``: parallax cos < 0.9998, depth > 0 in both, 2-DoF reprojection chi-square in
both, distance ratio following the octave ratio), but without the dense (free x free) band mask
and brute-force matcher (~16 ms a pair on KITTI's ~1400 x 1200 free keypoints): every epipolar
line passes through the epipole, so b's keypoints sorted by their angle around it give each
a-keypoint's line a short range of candidates (``band_pairs``), and only those pairs get a
Hamming distance and the band test (same matches, ~3.5 ms a pair: docs/notes/s14-triangulate.md).

Landmark ids: tracking numbers its landmarks with a dense counter from 0 in another process,
so the mapper's own landmarks take ids from ``MappingParams.triangulate_id_base`` upwards (a
range tracking does not reach; ``check_tracker_ids`` says so clearly if it ever does).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.frontend.geometry import se3_inv
from canopy.frontend.matching import as_words, band_pairs, best_two, hamming_pairs, unique_by_reference
from canopy.mono.triangulation import _EPIPOLE_MIN_PX, checked_points
from shared.types import StereoCalibration


@dataclass(frozen=True)
class PairGates:
    """The gates ``new_points_between`` reads (the names of ``MonoParams``' fields)."""

    epipolar_chi2: float
    triangulation_max_hamming: int
    triangulation_ratio: float
    chi2_mono: float
    min_parallax_deg: float = 0.0   # beyond ORB-SLAM's cos < 0.9998 (~1.15 deg)


def pair_gates(params) -> PairGates:
    """``PairGates`` from ``MappingParams`` (mapping.triangulate_*)."""
    return PairGates(params.triangulate_epipolar_chi2, params.triangulate_max_hamming,
                     params.triangulate_ratio, params.chi2_mono, params.triangulate_min_parallax_deg)


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
                              scale: float, pixel_sigma: float, blocked: dict[int, np.ndarray] | None = None):
    """Match and triangulate ``rec``'s free keypoints with each partner's in turn (best partner
    first; a keypoint used by one pair is no longer free for the next, as in ORB-SLAM).
    Returns a list of (partner index, rows of rec, rows of partner, world points (K,3)); the
    ``landmark`` arrays are not changed (the caller assigns ids), free rows are tracked here.
    ``blocked`` (keyframe index -> bool per keypoint) marks keypoints never to triangulate."""
    blocked = blocked or {}
    taken = _free(rec, blocked.get(rec.index))
    out = []
    for k in partners:
        b = keyframes[k]
        view = _FreeView(rec, taken)
        ka, kb, Pw = match_pair(view, _FreeView(b, _free(b, blocked.get(k))), calib, gates, scale, pixel_sigma)
        if len(ka):
            taken[ka] = 0   # any id >= 0: used
            out.append((k, ka, kb, Pw))
    return out


def match_pair(a, b, calib: StereoCalibration, gates: PairGates, scale: float, pixel_sigma: float = 1.0):
    """New points between the free keypoints (``landmark < 0``) of keyframes ``a`` and ``b``
    (records with ``T_world_cam``, ``uv``, ``octave``, ``descriptors``, ``landmark``): returns
    (rows of a, rows of b, world points (K,3)), as ``new_points_between``."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)))
    ia = np.flatnonzero(a.landmark < 0)
    ib = np.flatnonzero(b.landmark < 0)
    if len(ia) == 0 or len(ib) == 0:
        return empty
    K = calib.K
    Kinv = np.linalg.inv(K)
    Tb = se3_inv(b.T_world_cam)
    T_ba = Tb @ a.T_world_cam                      # camera a -> camera b
    R, t = T_ba[:3, :3], T_ba[:3, 3]
    # fundamental matrix x_b^T F x_a = 0 (Hartley-Zisserman Eq. 9.2: F = K^-T [t]x R K^-1)
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = Kinv.T @ tx @ R @ Kinv
    ha = np.column_stack([a.uv[ia], np.ones(len(ia))])
    lines = ha @ F.T                                                   # (na,3) lines in image b
    lines /= np.maximum(np.linalg.norm(lines[:, :2], axis=1), 1e-30)[:, None]
    # candidates without the dense band mask: every epipolar line in b passes through the
    # epipole e, so a line is an angle around e, and a keypoint at distance r from e lies within
    # tol of a line iff its angle is within asin(tol / r) of the line's. Keypoints nearer e than
    # _EPIPOLE_MIN_PX carry no depth and are skipped (ORB-SLAM SearchForTriangulation), and b's
    # keypoints go in rings of distance (each ring's window from its inner radius), sorted by
    # angle, so each line gets short ranges (``band_pairs``). With a's centre in front of b the
    # point at depth 0..inf runs from e to the ray's vanishing point: the angle is directed
    # (0..2 pi) and the half-line behind e is not searched. With the epipole (nearly) at infinity
    # the lines are parallel: keypoints sorted by their offset along the common normal instead.
    s_all = scale ** b.octave[ib]
    tol_all = np.sqrt(gates.epipolar_chi2) * pixel_sigma * s_all
    eh = K @ t
    groups = []        # (rows of ib, their keys, half window, period or None)
    if abs(eh[2]) * 1e5 > np.linalg.norm(eh[:2]):
        e = eh[:2] / eh[2]
        rel = b.uv[ib] - e
        r = np.sqrt((rel ** 2).sum(1))
        far = r > _EPIPOLE_MIN_PX * s_all
        ang_b = np.arctan2(rel[:, 1], rel[:, 0])
        if t[2] > 0:   # directed: from e towards the vanishing point K R x_a
            v = ha @ (K @ R @ Kinv).T
            ok = v[:, 2] > 1e-9
            with np.errstate(divide="ignore", invalid="ignore"):
                d = v[:, :2] / v[:, 2:3] - e
            key_a = np.where(ok, np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi), np.nan)
            key_b, period = np.mod(ang_b, 2 * np.pi), 2 * np.pi
        else:
            key_a = np.mod(np.arctan2(lines[:, 0], -lines[:, 1]), np.pi)   # line direction (-n_y, n_x)
            key_b, period = np.mod(ang_b, np.pi), np.pi
        edges = _EPIPOLE_MIN_PX * 2.0 ** np.arange(8)
        # groups by ring and by octave (0-2, 3+: the band is 1.2^octave wider)
        ring = (np.searchsorted(edges, r, side="right") - 1) * 2 + (b.octave[ib] >= 3)
        for g in np.unique(ring[far]).tolist():
            m = np.flatnonzero(far & (ring == g))
            half = float(np.arcsin(min(1.0, tol_all[m].max() / r[m].min())))
            groups.append((m, key_b[m], half, period))
    else:
        n = np.array([-eh[1], eh[0]]) / max(float(np.linalg.norm(eh[:2])), 1e-30)
        sign = np.where(lines[:, :2] @ n < 0, -1.0, 1.0)
        key_a = -lines[:, 2] * sign
        groups.append((np.arange(len(ib)), b.uv[ib] @ n, float(tol_all.max()), None))
    # the queries sorted once (searchsorted of sorted queries is ~3x faster); NaN keys (no
    # direction) sort last and find nothing
    qa_order = np.argsort(key_a, kind="stable")
    ka_sorted = key_a[qa_order]
    qs, js = [], []
    for m, key, half, period in groups:
        order = np.argsort(key, kind="stable")
        rows, ks = m[order], key[order]
        if period is not None:   # angles wrap: the sorted keys once more on either side
            rows = np.concatenate([rows, rows, rows])
            ks = np.concatenate([ks - period, ks, ks + period])
        qi, rj = band_pairs(ka_sorted - half, ka_sorted + half, ks)
        qs.append(qa_order[qi])
        js.append(ib[rows[rj]])
    qi = np.concatenate(qs) if qs else np.zeros(0, np.int64)
    jb = np.concatenate(js) if js else np.zeros(0, np.int64)
    if len(qi) == 0:
        return empty
    # Hamming first: a pair farther than max_hamming / ratio can neither be the accepted best
    # nor make an accepted best fail the ratio test, so dropping it changes no result and leaves
    # ~2 % of the pairs for the band test (random ORB descriptors are ~128 bits apart)
    ham = hamming_pairs(as_words(a.descriptors), as_words(b.descriptors), ia[qi], jb)
    keep = ham <= gates.triangulation_max_hamming / gates.triangulation_ratio
    qi, jb, ham = qi[keep], jb[keep], ham[keep]
    ub = b.uv[jb]
    dist_px = np.abs(lines[qi, 0] * ub[:, 0] + lines[qi, 1] * ub[:, 1] + lines[qi, 2])
    keep = dist_px < np.sqrt(gates.epipolar_chi2) * pixel_sigma * scale ** b.octave[jb]
    qi, jb, ham = qi[keep], jb[keep], ham[keep]
    if len(qi) == 0:
        return empty
    best, best_d, second_d = best_two(qi, jb, ham, len(ia))
    q = np.flatnonzero((best >= 0) & (best_d <= gates.triangulation_max_hamming)
                       & (best_d < gates.triangulation_ratio * second_d))
    if len(q) == 0:
        return empty
    u = unique_by_reference(q, best[q], best_d[q])
    ka, kb = ia[q[u]], best[q[u]]
    good, Pw = checked_points(a, b, ka, kb, calib, gates.chi2_mono, scale, pixel_sigma)
    if gates.min_parallax_deg > 0:   # depth error grows as 1 / parallax: far points need more
        ra, rb = Pw - a.T_world_cam[:3, 3], Pw - b.T_world_cam[:3, 3]
        cos = (ra * rb).sum(1) / np.maximum(np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1), 1e-30)
        good &= cos < np.cos(np.radians(gates.min_parallax_deg))
    return ka[good], kb[good], Pw[good]


def _free(rec, blocked: np.ndarray | None) -> np.ndarray:
    """``rec.landmark`` with the blocked keypoints marked used (a copy)."""
    taken = rec.landmark.copy()
    if blocked is not None:
        taken[blocked & (taken < 0)] = 0
    return taken


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
