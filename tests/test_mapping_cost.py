"""Local mapping's cheaper steps give the results of their plain definitions (issue 8, s17-mapcost)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy.backend.local_mapper import distinctive_index


def _reference_distinctive(desc: np.ndarray) -> np.ndarray:
    """ORB-SLAM's ComputeDistinctiveDescriptors as written there: per landmark, the observation whose
    median Hamming distance to the others is least (the first on ties)."""
    bits = np.unpackbits(desc, axis=-1).astype(np.int64)                     # (G,n,256)
    D = np.abs(bits[:, :, None, :] - bits[:, None, :, :]).sum(-1)           # (G,n,n)
    return np.array([int(np.argmin([np.median(row) for row in d])) for d in D])


@pytest.mark.parametrize("n", [3, 4, 5, 8, 13, 20, 21])
def test_distinctive_index_is_the_least_median_distance_observation(n):
    rng = np.random.default_rng(n)
    # observations of one landmark: a base descriptor with a few flipped bytes (so medians tie often)
    base = rng.integers(0, 256, (64, 1, 32), dtype=np.uint8)
    flips = ((rng.random((64, n, 32)) < 0.04) * rng.integers(1, 256, (64, n, 32))).astype(np.uint8)
    desc = base ^ flips
    ref = _reference_distinctive(desc)
    assert np.array_equal(distinctive_index(desc), ref)
    # and on unrelated descriptors (large distances, an uint16 sum of up to 256 per pair)
    far = rng.integers(0, 256, (16, n, 32), dtype=np.uint8)
    assert np.array_equal(distinctive_index(far), _reference_distinctive(far))
