"""s33: import to cap each pixel's |difference| in the sub-pixel SAD at TRUNC grey levels (environment; 0: off):
a truncated (robust) matching cost, so that the pixels of a window that lie at another depth (the background
behind an occluding contour) add a constant instead of a slope to the cost around the foreground's minimum."""
import os

import numpy as np

import canopy.frontend.stereo as stereo

T = int(os.environ.get("TRUNC", "0"))


def _centre_sad(patch_l, band, n_shifts, sum_type):
    P = patch_l.shape[1]
    w = P // 2
    k = len(patch_l)
    pl = patch_l.transpose(1, 2, 0).astype(np.int16, order="C")
    bd = band.transpose(1, 2, 0).astype(np.int16, order="C")
    pl -= pl[w, w]
    sad = np.empty((n_shifts, k), np.float64)
    diff = np.empty((P, P, k), np.int16)
    for shift in range(n_shifts):
        np.subtract(bd[:, shift:shift + P], pl, out=diff)
        diff -= bd[w, shift + w]
        np.abs(diff, out=diff)
        np.minimum(diff, T, out=diff)
        sad[shift] = diff.reshape(P * P, k).sum(axis=0, dtype=np.int32)
    return sad.T


def _zero_mean_sad(patch_l, band, n_shifts):
    k, P = patch_l.shape[0], patch_l.shape[1]
    n = P * P
    pl = patch_l.astype(np.int32) * n
    pl -= patch_l.reshape(k, -1).sum(axis=1, dtype=np.int32)[:, None, None]
    band_n = band.astype(np.int32) * n
    cols = np.zeros((k, band.shape[2] + 1), np.int64)
    np.cumsum(band.sum(axis=1, dtype=np.int32), axis=1, out=cols[:, 1:])
    sad = np.empty((k, n_shifts), np.float64)
    diff = np.empty(pl.shape, np.int32)
    for shift in range(n_shifts):
        np.subtract(band_n[:, :, shift:shift + P], pl, out=diff)
        diff -= (cols[:, shift + P] - cols[:, shift]).astype(np.int32)[:, None, None]
        np.abs(diff, out=diff)
        np.minimum(diff, T * n, out=diff)
        sad[:, shift] = diff.reshape(k, -1).sum(axis=1, dtype=np.int64)
    return sad / n


if T > 0:
    stereo._centre_sad = _centre_sad
    stereo._zero_mean_sad = _zero_mean_sad
