"""shared.arrays: the sort-based unique gives what np.unique gives."""
from __future__ import annotations

import numpy as np

from shared.arrays import unique_sorted


def test_unique_sorted_equals_np_unique_on_ids():
    rng = np.random.default_rng(4)
    cases = [np.zeros(0, np.int64), np.array([7]), np.array([3, 3, 3]), rng.integers(-5, 5, 40),
             rng.integers(0, 50_000, 7_000), rng.integers(0, 2**40, 900), rng.integers(0, 8, (30, 20)),
             rng.integers(0, 256, 500).astype(np.uint8), rng.random(300) < 0.5, rng.normal(size=200)]
    for a in cases:
        got, want = unique_sorted(a), np.unique(a)
        assert got.dtype == want.dtype and np.array_equal(got, want)
    ids = [5, 1, 5, 2]
    out = unique_sorted(ids)
    assert out.tolist() == [1, 2, 5] and ids == [5, 1, 5, 2]   # the input is left alone
