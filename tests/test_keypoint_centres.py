"""ORB keypoints on pyramid levels in pixel-centre-aligned level-0 coordinates
(canopy.frontend.keypoint_centres): a corner found in an image and in its mirror image must
land on mirrored positions, on every pyramid level."""
from pathlib import Path

import cv2
import numpy as np

from canopy.frontend.features import OrbExtractor
from canopy.frontend.keypoint_centres import centre_keypoints, level_maps
from canopy.frontend.params import TrackingParams

DATA = Path(__file__).resolve().parents[1] / "data" / "kitti06_snippet" / "image_l"


def _mirror_offsets(image: np.ndarray, centred: bool) -> dict[int, float]:
    """Per level: median horizontal offset between the keypoints of ``image`` and the mirrored
    keypoints of its mirror image (0 when positions are mirror-consistent)."""
    params = TrackingParams(n_features=3000, oversample=1.0, parallel_extraction=False)
    ext = OrbExtractor(params)
    w = image.shape[1]
    a = ext.extract(image)
    b = ext.extract(np.ascontiguousarray(image[:, ::-1]))
    if centred:
        scales = params.scale_factor ** np.arange(params.n_levels)
        a, _ = centre_keypoints(a, None, scales, w, image.shape[0])
        b, _ = centre_keypoints(b, None, scales, w, image.shape[0])
    out = {}
    for level in range(1, params.n_levels):
        pa = a.uv[a.octave == level].astype(np.float64)
        pb = b.uv[b.octave == level].astype(np.float64)
        pb[:, 0] = (w - 1) - pb[:, 0]
        if len(pa) < 20 or len(pb) < 20:
            continue
        d = np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=2)
        j = d.argmin(axis=1)
        ok = d[np.arange(len(pa)), j] < 2.0 * params.scale_factor**level
        out[level] = float(np.mean(pa[ok, 0] - pb[j[ok], 0]) / 2.0)  # positions are quantised per level: mean
    return out


def test_level_maps_shift_by_half_a_level_pixel():
    scales = 1.2 ** np.arange(8)
    a, b = level_maps(752, scales)
    assert a[0] == 1.0 and b[0] == 0.0
    np.testing.assert_allclose(a, 1.0, atol=3e-3)             # rounded level sizes: < 0.3 % zoom
    np.testing.assert_allclose(b, 0.5 * (scales - 1.0), atol=0.02)  # (x_L + 0.5) s - 0.5 vs x_L s


def test_centred_keypoints_are_mirror_consistent():
    image = cv2.imread(str(sorted(DATA.glob("*.png"))[0]), cv2.IMREAD_GRAYSCALE)
    raw = _mirror_offsets(image, centred=False)
    centred = _mirror_offsets(image, centred=True)
    assert len(raw) >= 5
    # OpenCV's coordinates sit ~0.5 (s^L - 1) px left of the corner (1.6 px on level 7 here)
    assert np.mean(list(raw.values())) < -0.3, raw
    assert max(abs(v) for v in raw.values()) > 1.0, raw
    # mapped through the pyramid's own resize chain they agree on every level
    assert max(abs(v) for v in centred.values()) < 0.02, centred
