"""Row alignment of a rectified stereo pair, measured from its own images (no calibration target).

Stereo matching here, as in ORB-SLAM, searches the right image along the left keypoint's row: the
pair is assumed rectified, so a point's two images share a row. A residual of the rectification
breaks that by a fraction of a pixel that varies over the image, and the matcher's SAD window then compares
patches a little off each other vertically. For texture that is not vertical, that error turns into
a horizontal, disparity error.

The rows' misalignment is measured directly. For each stereo match, the right patch is searched over
±``search`` rows at the matched column (zero-mean squared differences of a (2w+1)² window, parabola vertex), which
gives the right image's row offset at that point. Then v_r − v_l = a + b (u − cx) + c (v − cy) is
fitted (a Huber M-estimate; standard errors by a jackknife over frames):
- a is a constant offset (a relative pitch of the rectified cameras);
- b a row offset growing across the image (a relative roll of θ = b rad turns (x, y) into
  (x − θy, y + θx));
- c one growing down it (the two cameras' vertical focal lengths differ by a fraction c).

Measured with ``tools/check_rectification.py`` (every frame, the config's matcher):
- the bundled KITTI 06 snippet: v_r − v_l = −0.055 − 4.04e-4 (±2.7e-5) (u − cx) + 8.3e-4 (±9e-5) (v − cy), i.e.
  up to 0.46 px at the image's corners (roll −0.023°);
- the bundled EuRoC snippet, rectified by OpenCV at load time: within 0.19 px everywhere.

What limits the measurement: a row field put into a real KITTI pair by bicubic resampling is read back within
7 % (0.4 px as 0.374, a roll of 3e-4 as 3.00e-4; ``tests/test_row_alignment.py``). The frames' jackknife does not
include a bias the scene's texture puts into every frame alike: the static EuRoC snippet sees one scene, and a
zero-mean SAD instead of the squared differences reads its corners at 0.08 px.

Re-aligning KITTI's rows by its fit did not change the trajectory (21.4 → 22.0 mm, docs/notes/s32-oracle.md §7),
so the misalignment is reported, not corrected.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy.frontend.stereo import parabola_minimum


MIN_SHARPNESS = 1.0   # the SSD's rise one row either side of its minimum, over the minimum (see patch_row_offsets)


@dataclass(frozen=True)
class RowMisalignment:
    """The fitted row offset of the right image, v_r − v_l = offset + roll (u − cx) + row_scale (v − cy)."""

    offset_px: float
    roll_rad: float
    row_scale: float
    offset_se: float
    roll_se: float
    row_scale_se: float
    n_matches: int
    residual_px: float            # robust sd of the per-match offsets about the fit
    corners_px: tuple             # the fitted offset at the corners (top-left, top-right, bottom-left, bottom-right)

    @property
    def worst_corner_px(self) -> float:
        return float(max(abs(c) for c in self.corners_px))

    def as_dict(self) -> dict:
        return {"offset_px": self.offset_px, "roll_rad": self.roll_rad, "roll_deg": float(np.degrees(self.roll_rad)),
                "row_scale": self.row_scale, "offset_se": self.offset_se, "roll_se": self.roll_se,
                "row_scale_se": self.row_scale_se, "n_matches": self.n_matches, "residual_px": self.residual_px,
                "corners_px": list(self.corners_px), "worst_corner_px": self.worst_corner_px}


def _grey_pair(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    for name, img in (("left", left), ("right", right)):
        a = np.asarray(img) if img is not None else None
        if a is None or a.ndim != 2 or a.size == 0:
            raise ValueError(f"patch_row_offsets: {name} image must be a non-empty 2-D grey image, got "
                             + ("None" if a is None else f"shape {a.shape}"))
    if np.shape(left) != np.shape(right):
        raise ValueError(f"patch_row_offsets: left and right images differ in size ({np.shape(left)} vs {np.shape(right)})")
    return np.asarray(left, np.int32), np.asarray(right, np.int32)


def patch_row_offsets(left: np.ndarray, right: np.ndarray, u_left: np.ndarray, v_left: np.ndarray,
                      u_right: np.ndarray, half_window: int = 5, search: int = 2,
                      min_sharpness: float = MIN_SHARPNESS) -> tuple[np.ndarray, np.ndarray]:
    """For stereo matches (left keypoint (u_left, v_left), right column u_right, level-0 pixels): the right
    patch's sub-pixel row offset from the left keypoint's row, v_r − v_l. Returns (indices of the matches
    measured, their offsets). A match is measured when both windows fit in the image and the zero-mean squared
    difference over the rows −search..search has an interior minimum, sharp enough (``min_sharpness``)."""
    L, R = _grey_pair(left, right)
    u_left, v_left, u_right = (np.asarray(x, np.float64).ravel() for x in (u_left, v_left, u_right))
    if not len(u_left) == len(v_left) == len(u_right):
        raise ValueError(f"patch_row_offsets: u_left, v_left, u_right differ in length "
                         f"({len(u_left)}, {len(v_left)}, {len(u_right)})")
    if half_window < 1 or search < 1:
        raise ValueError(f"patch_row_offsets: half_window and search must be >= 1 (got {half_window}, {search})")
    h, w = L.shape
    ul, vl, ur = np.rint(u_left).astype(np.int64), np.rint(v_left).astype(np.int64), np.rint(u_right).astype(np.int64)
    k = half_window
    inside = ((vl - k - search >= 0) & (vl + k + search < h) & (ul - k >= 0) & (ul + k < w)
              & (ur - k >= 0) & (ur + k < w))
    idx = np.flatnonzero(inside)
    if len(idx) == 0:
        return idx, np.zeros(0)
    ul, vl, ur = ul[idx], vl[idx], ur[idx]
    offs = np.arange(-k, k + 1)
    rows = offs[None, :, None]
    cols = offs[None, None, :]
    pl = L[vl[:, None, None] + rows, ul[:, None, None] + cols]
    pl = pl - pl.mean(axis=(1, 2), keepdims=True)     # zero-mean: the two cameras' exposure may differ
    costs = np.empty((len(idx), 2 * search + 1))
    for j, s in enumerate(range(-search, search + 1)):
        pr = R[vl[:, None, None] + s + rows, ur[:, None, None] + cols]
        diff = pr - pr.mean(axis=(1, 2), keepdims=True) - pl
        costs[:, j] = (diff * diff).sum(axis=(1, 2))
    best, delta, d2, ok = parabola_minimum(costs, search)   # the disparity's own vertex, along the rows
    i = np.arange(len(idx))
    b = np.clip(best, 1, 2 * search - 1)
    d1, d3 = costs[i, b - 1], costs[i, b + 1]
    # the aperture problem: a window of vertical edges only has a cost that barely changes with the row, and its
    # vertex is noise about its whole row (0): kept only where the cost rises by min_sharpness x its minimum
    # one row away, i.e. the window has texture across the rows
    ok &= (d1 + d3 - 2.0 * d2) >= min_sharpness * np.maximum(d2, 1e-9)
    return idx[ok], (best - search + delta)[ok]


def _huber_fit(A: np.ndarray, y: np.ndarray, k: float, iterations: int) -> tuple[np.ndarray, float]:
    """Huber M-estimate of y ~ A coef by iteratively reweighted least squares, the scale re-estimated each
    round (1.4826 x the median absolute residual); returns (coef, that scale)."""
    w = np.ones(len(y))
    sigma = 1.0
    coef = np.zeros(A.shape[1])
    for _ in range(max(1, iterations)):
        sw = np.sqrt(w)
        coef = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)[0]
        r = y - A @ coef
        sigma = max(1.4826 * float(np.median(np.abs(r))), 1e-6)
        a = np.abs(r) / (k * sigma)
        w = np.where(a <= 1.0, 1.0, 1.0 / np.maximum(a, 1e-12))
    return coef, sigma


def fit_row_misalignment(u: np.ndarray, v: np.ndarray, offsets: np.ndarray, cx: float, cy: float,
                         width: int, height: int, groups: np.ndarray | None = None, huber_k: float = 1.345,
                         iterations: int = 20, max_offset: float = 1.5) -> RowMisalignment:
    """Huber fit of offsets = a + b (u − cx) + c (v − cy) over the matches within ``max_offset`` px (at least 10).

    ``groups`` (one label per match, e.g. its frame): the standard errors come from a leave-one-group-out
    jackknife when there are at least 3 groups. The offsets of one frame share its scene, so their errors are
    not independent. On KITTI 06 the roll's scatter between blocks of 6 frames is 3-4 x what the
    independent-error formula gives. Without ``groups`` they are that formula's."""
    u, v, y = (np.asarray(x, np.float64).ravel() for x in (u, v, offsets))
    if not len(u) == len(v) == len(y):
        raise ValueError(f"fit_row_misalignment: u, v, offsets differ in length ({len(u)}, {len(v)}, {len(y)})")
    keep = np.abs(y) <= max_offset
    if keep.sum() < 10:
        raise ValueError(f"fit_row_misalignment: {int(keep.sum())} usable matches, need at least 10")
    A = np.stack([np.ones(len(u)), u - cx, v - cy], axis=1)[keep]
    y = y[keep]
    coef, sigma = _huber_fit(A, y, huber_k, iterations)
    labels = None if groups is None else np.asarray(groups).ravel()
    if labels is not None and len(labels) != len(keep):
        raise ValueError(f"fit_row_misalignment: groups has {len(labels)} labels for {len(keep)} matches")
    uniq = np.unique(labels[keep]) if labels is not None else np.zeros(0)
    if len(uniq) >= 3:
        g = labels[keep]
        loo = np.array([_huber_fit(A[g != lab], y[g != lab], huber_k, iterations)[0] for lab in uniq
                        if (g != lab).sum() >= 10])
        se = np.sqrt((len(loo) - 1) / len(loo) * ((loo - loo.mean(axis=0)) ** 2).sum(axis=0))
    else:
        se = np.sqrt(np.diag(np.linalg.inv(A.T @ A))) * sigma
    corners = [(0.0, 0.0), (width - 1.0, 0.0), (0.0, height - 1.0), (width - 1.0, height - 1.0)]
    at = tuple(float(coef[0] + coef[1] * (cu - cx) + coef[2] * (cv - cy)) for cu, cv in corners)
    return RowMisalignment(float(coef[0]), float(coef[1]), float(coef[2]), float(se[0]), float(se[1]), float(se[2]),
                           int(len(y)), float(sigma), at)
