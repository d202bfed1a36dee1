"""s32: import to make refinement_pair's smoothing a vertical-only Gaussian (VB px along columns, HB px along
rows, environment variables). Experiment only (measured worse, docs/notes/s32-oracle.md)."""
import os, cv2, numpy as np
import canopy.frontend.noisy_features as nf
import canopy.frontend.stereo as st, canopy.frontend.stereo_fill as sf, canopy.frontend.stereo_flow as sfl
from canopy.enhance.noise import estimate_noise
VB = float(os.environ.get('VB', '2'))
HB = float(os.environ.get('HB', '0'))
k = cv2.getGaussianKernel(int(2 * round(3 * VB) + 1), VB)
kx = cv2.getGaussianKernel(int(2 * round(3 * HB) + 1), HB) if HB > 0 else np.ones((1, 1))
def refinement_pair(left_img, right_img, params, left_sigma=None):
    if params.subpixel_denoise_sigma <= 0:
        return left_img, right_img, None
    sigma = estimate_noise(left_img, rows_fraction=0.5) if left_sigma is None else left_sigma
    if sigma < params.subpixel_denoise_sigma:
        return left_img, right_img, sigma
    blur = lambda img: cv2.sepFilter2D(img, -1, kx, k)
    return blur(left_img), blur(right_img), sigma
for m in (nf, st, sf, sfl):
    m.refinement_pair = refinement_pair
