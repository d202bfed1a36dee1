"""The scene's "up" in one image, from the vanishing direction of its vertical line segments.

Idea (the classic vanishing-point geometry, e.g. Hartley & Zisserman 2nd ed. §8.6; Collins & Weiss 1990;
Bazin et al. 2012 on the Gaussian sphere): a segment with endpoints p1, p2 (pixels) and the camera centre span its
*interpretation plane*, with unit normal n = (K⁻¹p̃1 × K⁻¹p̃2)/‖·‖. The 3-D line lies in that plane, so its
direction d satisfies n·d = 0. Every world-vertical edge (tree trunks and posts in the generated orchard; poles
and building edges on KITTI) shares the direction "up", so up is the common null direction of their normals:
two of them give a hypothesis v = n_i × n_j, all of them the smallest eigenvector of Σ wᵢ nᵢnᵢᵀ.

Here (our own code): segments from ``canopy.lines.features.detect_segments`` (FLD on the half-size image: Canny is
most of the cost); the candidates are the segments whose interpretation plane passes within ``max_prior_deg`` of
the predicted up (the tracker's pose) or, without a prediction, within ``upright_gate_deg`` of −y (a roughly
upright camera); each candidate is refitted to the sub-pixel position of its edge on the full image
(``refine_segments_subpixel``: FLD's line sits on Canny's integer edge pixels, and the angle of a near-vertical
segment is all a vanishing direction is made of — day-loop hazy cell p90 0.79 -> 0.46 deg, s25 note);
a deterministic RANSAC enumerates the
pairs of the longest candidates and scores each hypothesis by the length of the candidates it explains
(residual |asin(nᵢ·v)| < ``inlier_deg``); the winner is refined by the length-weighted eigenvector, with inliers
re-selected a few times; the sign makes y < 0 (camera y points down).

Sigma: weighted least squares with residual variance c/wᵢ; c is estimated from the inliers' residuals
(Σ wᵢrᵢ²/(N−2)) and the tangent-plane information is M/c with M = Σ wᵢ nᵢnᵢᵀ restricted to the plane ⟂ v (its two
larger eigenvalues λ₂ ≤ λ₃). ``sigma_deg`` is the worse axis (in practice pitch: a vertical's image angle says
little about pitch near the image's centre column), √(c/λ₂), times ``sigma_scale`` (measured on the generated
cells, docs/notes/s25-vertical.md: the residuals of one trunk's two edges are not independent) and never below
``sigma_floor_deg`` (a guard for a few near-coincident inliers; not binding on the measured cells).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy.lines.features import detect_segments, segment_lengths
from canopy.lines.params import LineParams
from shared.errors import ConfigError, InputError

UPRIGHT_UP_CAM = np.array([0.0, -1.0, 0.0])  # camera x right, y down, z forward


@dataclass(frozen=True)
class VerticalEstimate:
    up_cam: np.ndarray   # (3,) unit vector: the scene's "up" in the camera frame (x right, y down, z forward), y < 0
    sigma_deg: float     # angular 1-sigma of up_cam
    n_inliers: int       # segments that agree with it


@dataclass(frozen=True)
class VerticalParams:
    # the search window: the interpretation plane of a candidate passes within this angle of the predicted up
    max_prior_deg: float = 5.0
    upright_gate_deg: float = 30.0       # without a prediction: up within this of -y (an upright camera)
    inlier_deg: float = 0.5              # |asin(n·v)| of an inlier
    ransac_segments: int = 24            # RANSAC pairs among the longest candidates (24 -> 276 hypotheses)
    refine_iterations: int = 3           # eigenvector refinement, inliers re-selected each time
    min_inliers: int = 4
    max_sigma_deg: float = 2.0           # a worse estimate is None
    sigma_scale: float = 1.2             # measured: pitch error p50 / 0.674 over sigma p50, 0.9-1.6 per cell (s25 note)
    sigma_floor_deg: float = 0.05
    min_pair_angle_deg: float = 2.0      # two planes closer than this do not define a direction
    # sub-pixel refit of the candidate segments on the image's edge profile (refine_segments_subpixel)
    subpixel: bool = True
    subpixel_samples: int = 24           # profiles across each segment
    subpixel_reach_px: float = 3.0       # the edge is sought within this of the detected line
    # segment detection (canopy.lines.features) on the image shrunk by ``detect_downscale`` (1 or 2; INTER_AREA):
    # FLD's Canny is most of the time; the sub-pixel refit then runs on the full image (its reach covers the shrunk
    # detection's ~1 px error). Measured (s25 note, 752x480): full size with 2 % segments 13 ms on day-loop clean
    # and p50 0.22 deg; half size with 4 % of its diagonal (36 full-size px) 4.5 ms and p50 0.17 deg
    detect_downscale: int = 2
    detector: str = "fld"
    min_length_fraction: float = 0.04    # of the (shrunk) image's diagonal
    max_lines: int = 300
    line_params: LineParams = field(init=False, repr=False, compare=False)

    def validate(self) -> "VerticalParams":
        def need(ok: bool, name: str, what: str) -> None:
            if not ok:
                raise ConfigError("VerticalParams", f"{name} {what} (got {getattr(self, name)!r})")

        need(0 < self.max_prior_deg < 90, "max_prior_deg", "must be in (0, 90)")
        need(0 < self.upright_gate_deg < 90, "upright_gate_deg", "must be in (0, 90)")
        need(0 < self.inlier_deg < 30, "inlier_deg", "must be in (0, 30)")
        need(self.ransac_segments >= 2, "ransac_segments", "must be >= 2")
        need(self.refine_iterations >= 1, "refine_iterations", "must be >= 1")
        need(self.min_inliers >= 3, "min_inliers", "must be >= 3 (two give a direction with no check)")
        need(self.max_sigma_deg > 0, "max_sigma_deg", "must be > 0")
        need(self.sigma_scale > 0, "sigma_scale", "must be > 0")
        need(self.sigma_floor_deg >= 0, "sigma_floor_deg", "must be >= 0")
        need(0 < self.min_pair_angle_deg < 90, "min_pair_angle_deg", "must be in (0, 90)")
        need(self.subpixel_samples >= 4, "subpixel_samples", "must be >= 4")
        need(0.5 <= self.subpixel_reach_px <= 8, "subpixel_reach_px", "must be in [0.5, 8]")
        need(self.detect_downscale in (1, 2), "detect_downscale", "must be 1 or 2")
        return self

    def __post_init__(self):
        self.validate()
        # LineParams checks the detector fields (detector name, length fraction, max_lines)
        object.__setattr__(self, "line_params", LineParams(detector=self.detector,
                                                           min_length_fraction=self.min_length_fraction,
                                                           max_lines=self.max_lines))


def _check_K(K) -> np.ndarray:
    K = np.asarray(K, np.float64) if K is not None else None
    if K is None or K.shape != (3, 3) or not np.isfinite(K).all():
        raise InputError("estimate_vertical", f"K must be a finite 3x3 matrix, got {None if K is None else K.shape}")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or abs(K[2, 2] - 1.0) > 1e-9 or np.any(K[2, :2] != 0) or K[1, 0] != 0:
        raise InputError("estimate_vertical", "K must be an upper-triangular pinhole matrix with fx, fy > 0 and "
                         f"K[2] = (0, 0, 1), got {K.tolist()}")
    return K


def _unit_prior(prior_up_cam) -> np.ndarray:
    v = np.asarray(prior_up_cam, np.float64).reshape(-1)
    n = np.linalg.norm(v) if v.shape == (3,) else 0.0
    if v.shape != (3,) or not np.isfinite(v).all() or n < 1e-9:
        raise InputError("estimate_vertical", f"prior_up_cam must be a finite non-zero 3-vector, got {prior_up_cam!r}")
    return v / n


def interpretation_normals(segs: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N,3) unit normals of the planes through the camera centre and each segment (rows x1, y1, x2, y2)."""
    s = np.asarray(segs, np.float64).reshape(-1, 4)
    Kinv = np.linalg.inv(K)
    ones = np.ones((len(s), 1))
    r1 = np.hstack([s[:, 0:2], ones]) @ Kinv.T
    r2 = np.hstack([s[:, 2:4], ones]) @ Kinv.T
    n = np.cross(r1, r2)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def refine_segments_subpixel(image: np.ndarray, segs: np.ndarray, samples: int = 24,
                             reach_px: float = 2.0) -> np.ndarray:
    """Segments refitted to the sub-pixel position of their edge; (N,4) float64, same endpoints' extent.

    FLD fits its line to Canny's edge pixels (integer positions), so a near-vertical segment's angle is off by a
    few tenths of a pixel over its length; that angle is all the vanishing direction is made of. Here: ``samples``
    intensity profiles across each segment (bilinear, 1 px steps, ``reach_px`` + 1 either side; each the mean of
    three profiles 1 px apart along the segment against noise), the edge at the parabola-interpolated peak of
    |dI/dn| (the classic sub-pixel edge, e.g. Devernay 1995), then the weighted total-least-squares line through
    those points (weights: peak strength); the old endpoints are projected on it. A profile whose peak is at the
    end of its reach is dropped; a segment with fewer than half of its profiles kept stays as detected.
    """
    import cv2

    s = np.asarray(segs, np.float64).reshape(-1, 4)
    if len(s) == 0:
        return s.copy()
    p1, p2 = s[:, 0:2], s[:, 2:4]
    d = p2 - p1
    length = np.linalg.norm(d, axis=1, keepdims=True)
    t = d / np.maximum(length, 1e-9)                      # (N,2) along
    nrm = np.column_stack([-t[:, 1], t[:, 0]])           # (N,2) across
    win = 2                                              # differences either side of the peak
    half = int(np.ceil(reach_px)) + win + 1
    offs = np.arange(-half, half + 1, dtype=np.float64)  # (O,)
    frac = (np.arange(samples) + 0.5) / samples          # (S,)
    along = np.array([-1.0, 0.0, 1.0])                   # (A,) px
    centre = p1[:, None, :] + frac[None, :, None] * d[:, None, :]                        # (N,S,2)
    pts = (centre[:, :, None, None, :] + along[None, None, :, None, None] * t[:, None, None, None, :]
           + offs[None, None, None, :, None] * nrm[:, None, None, None, :])              # (N,S,A,O,2)
    n_seg, n_o = len(s), len(offs)
    # remap wants both sides of its map below 32767: one row per profile position (N*S rows)
    mx = pts[..., 0].reshape(n_seg * samples, -1).astype(np.float32)
    my = pts[..., 1].reshape(n_seg * samples, -1).astype(np.float32)
    vals = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    prof = vals.reshape(n_seg, samples, 3, n_o).mean(axis=2)                              # (N,S,O)
    diff = np.diff(prof, axis=2)                                                         # (N,S,O-1) at offs+0.5
    # the edge's polarity is the segment's (the stronger sign of its summed differences); the other sign is not it
    polarity = np.sign(diff.sum(axis=(1, 2)))[:, None, None]
    grad = np.maximum(diff * np.where(polarity == 0, 1.0, polarity), 0.0)
    k = np.argmax(grad, axis=2)
    inner = (k >= win) & (k < n_o - 1 - win)
    # centroid of the derivative over the peak ± ``win``: the area-preserving step position, exact for a
    # box-sampled step (a parabola through three differences has a sawtooth bias of ~0.1 px with the edge's phase,
    # which along a near-vertical line turns into an angle error)
    kc = np.clip(k, win, n_o - 2 - win)
    idx = kc[..., None] + np.arange(-win, win + 1)
    g = np.take_along_axis(grad, idx, 2)
    pos = offs[idx] + 0.5
    gsum = g.sum(axis=2)
    offset = (g * pos).sum(axis=2) / np.maximum(gsum, 1e-12)                             # (N,S) px across
    w = np.where(inner, gsum, 0.0)
    ok = (w > 0).sum(axis=1) >= samples // 2
    edge = centre + offset[..., None] * nrm[:, None, :]                                  # (N,S,2)
    wsum = np.maximum(w.sum(axis=1), 1e-12)
    mean = (w[..., None] * edge).sum(axis=1) / wsum[:, None]
    r = edge - mean[:, None, :]
    sxx = (w * r[..., 0] ** 2).sum(axis=1)
    syy = (w * r[..., 1] ** 2).sum(axis=1)
    sxy = (w * r[..., 0] * r[..., 1]).sum(axis=1)
    ang = 0.5 * np.arctan2(2 * sxy, sxx - syy)           # principal axis of the weighted edge points
    u = np.column_stack([np.cos(ang), np.sin(ang)])
    u *= np.sign(np.sum(u * t, axis=1, keepdims=True) + 1e-300)
    q1 = mean + np.sum((p1 - mean) * u, axis=1, keepdims=True) * u
    q2 = mean + np.sum((p2 - mean) * u, axis=1, keepdims=True) * u
    out = s.copy()
    out[ok] = np.hstack([q1, q2])[ok]
    return out


def _weighted_null_direction(normals: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(v, eigenvalues ascending, eigenvectors) of M = Σ wᵢ nᵢnᵢᵀ; v the smallest eigenvector."""
    M = (normals * w[:, None]).T @ normals
    lam, vec = np.linalg.eigh(M)
    return vec[:, 0], lam, vec


def estimate_vertical_from_segments(segs: np.ndarray, K: np.ndarray, prior_up_cam: np.ndarray | None = None,
                                    params: VerticalParams | None = None,
                                    image: np.ndarray | None = None) -> VerticalEstimate | None:
    """``estimate_vertical`` on given segments ((N,4) pixel endpoints), e.g. those the tracker already found;
    with ``image`` (the grey image they were found in) and ``params.subpixel`` the candidates are refitted to their
    edges first."""
    p = params or VerticalParams()
    K = _check_K(K)
    v0 = UPRIGHT_UP_CAM if prior_up_cam is None else _unit_prior(prior_up_cam)
    gate = np.radians(p.max_prior_deg if prior_up_cam is not None else p.upright_gate_deg)
    segs = np.asarray(segs, np.float64).reshape(-1, 4)
    if len(segs) < p.min_inliers:
        return None
    normals = interpretation_normals(segs, K)
    lengths = segment_lengths(segs)
    # candidates: the plane passes within the gate of the predicted up (|n·v0| = sin of v0's angle off the plane)
    cand = np.abs(normals @ v0) < np.sin(gate)
    if cand.sum() < p.min_inliers:
        return None
    n_c, w_c = normals[cand], lengths[cand]
    if p.subpixel and image is not None:
        n_c = interpretation_normals(refine_segments_subpixel(image, segs[cand], p.subpixel_samples,
                                                              p.subpixel_reach_px), K)
    sin_inlier = np.sin(np.radians(p.inlier_deg))

    # deterministic RANSAC: every pair of the longest candidates (detect_segments sorts longest first)
    top = np.argsort(-w_c, kind="stable")[: p.ransac_segments]
    i, j = np.triu_indices(len(top), 1)
    hyp = np.cross(n_c[top[i]], n_c[top[j]])
    norm = np.linalg.norm(hyp, axis=1)
    ok = norm > np.sin(np.radians(p.min_pair_angle_deg))
    hyp = hyp[ok] / norm[ok, None]
    hyp *= np.sign(hyp @ v0)[:, None]  # the sign towards the prediction
    hyp = hyp[hyp @ v0 > np.cos(gate)]
    if len(hyp) == 0:
        return None
    explained = np.abs(n_c @ hyp.T) < sin_inlier          # (candidates, hypotheses)
    score = w_c @ explained
    v = hyp[int(np.argmax(score))]

    inl = None
    for _ in range(p.refine_iterations):
        inl_new = np.abs(n_c @ v) < sin_inlier
        if inl_new.sum() < p.min_inliers:
            return None
        if inl is not None and np.array_equal(inl_new, inl):
            break
        inl = inl_new
        v_new, lam, vec = _weighted_null_direction(n_c[inl], w_c[inl])
        v = v_new * (1.0 if v_new @ v0 >= 0 else -1.0)
    if v @ v0 < np.cos(gate):
        return None
    n_in, w_in = n_c[inl], w_c[inl]
    _, lam, _ = _weighted_null_direction(n_in, w_in)
    n = int(inl.sum())
    r = n_in @ v
    c = float(w_in @ (r * r)) / max(n - 2, 1)
    lam_tangent = float(lam[1])  # the smaller of the two eigenvalues orthogonal to v
    if lam_tangent <= 0:
        return None
    sigma = np.degrees(np.sqrt(c / lam_tangent)) * p.sigma_scale
    sigma = max(float(sigma), p.sigma_floor_deg)
    if not np.isfinite(sigma) or sigma > p.max_sigma_deg:
        return None
    up = v if v[1] < 0 else -v
    return VerticalEstimate(up_cam=up, sigma_deg=sigma, n_inliers=n)


def detect_vertical_candidates(image: np.ndarray, params: VerticalParams) -> np.ndarray:
    """Segments (N,4) in full-image pixels, detected at ``params.detect_downscale``; raises InputError on a bad
    image (``detect_segments``' checks)."""
    if params.detect_downscale == 1 or image is None or not isinstance(image, np.ndarray) or image.ndim != 2 \
            or image.dtype != np.uint8:
        return detect_segments(image, params.line_params)[0]
    import cv2

    f = params.detect_downscale
    small = cv2.resize(image, (image.shape[1] // f, image.shape[0] // f), interpolation=cv2.INTER_AREA)
    segs, _ = detect_segments(small, params.line_params)
    return (segs.astype(np.float64) + 0.5) * f - 0.5  # pixel centres of the shrunk image in the full one


def estimate_vertical(image: np.ndarray, K: np.ndarray, prior_up_cam: np.ndarray | None = None,
                      params: "VerticalParams | None" = None) -> VerticalEstimate | None:
    """None when the image holds too little vertical structure to tell."""
    p = params or VerticalParams()
    K = _check_K(K)
    segs = detect_vertical_candidates(image, p)
    return estimate_vertical_from_segments(segs, K, prior_up_cam, p, image=image)
