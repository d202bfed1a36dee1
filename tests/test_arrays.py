"""shared.arrays: the sort-based unique gives what np.unique gives."""
from __future__ import annotations

import numpy as np

from shared.arrays import TABLE_SPAN_MAX, isin_ids, unique_sorted


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


def test_isin_ids_equals_np_isin():
    """The lookup-table np.isin gives np.isin's booleans: wide and narrow id ranges, negatives,
    empty sides, ids beyond the table's span (np.isin as it is), non-integer arrays."""
    rng = np.random.default_rng(5)
    ids = rng.integers(0, 30_000, 2_000)
    cases = [(rng.integers(0, 30_000, 2_500), ids), (rng.integers(-50, 50, 300), rng.integers(-20, 80, 40)),
             (np.zeros(0, np.int64), ids), (ids, np.zeros(0, np.int64)), (np.array([5, 2**40]), np.array([2**40, 0])),
             (rng.integers(0, 9, (7, 6)), np.array([1, 3])), (rng.random(50), rng.random(20)),
             (np.arange(10, dtype=np.uint8), np.array([3, 250], np.uint8)),
             (np.array([0, TABLE_SPAN_MAX + 1]), np.array([0, TABLE_SPAN_MAX + 1]))]
    for values, want in cases:
        got, ref = isin_ids(values, want), np.isin(values, want)
        assert got.shape == ref.shape and np.array_equal(got, ref)
