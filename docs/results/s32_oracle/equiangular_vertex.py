"""s32: import to replace the SAD parabola vertex with the equiangular (V) fit of Shimizu & Okutomi (2005), the
interpolant meant for SAD costs. Experiment only (measured worse on KITTI, docs/notes/s32-oracle.md)."""
import numpy as np
import canopy.frontend.stereo as st
def equiangular_minimum(sad, L):
    best = np.argmin(sad, axis=1)
    interior = (best > 0) & (best < 2 * L)
    idx = np.arange(len(sad))
    b = np.clip(best, 1, 2 * L - 1)
    d1, d2, d3 = sad[idx, b - 1], sad[idx, b], sad[idx, b + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(d3 < d1, (d1 - d3) / (2.0 * (d1 - d2)), (d1 - d3) / (2.0 * (d3 - d2)))
    delta = np.where(np.isfinite(delta) & interior, delta, 0.0)
    good = interior & (np.abs(delta) <= 1.0)
    return best, delta, sad[idx, best], good
st.parabola_minimum = equiangular_minimum
