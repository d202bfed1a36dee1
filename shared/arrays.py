"""Small array helpers shared by the hot paths.

``unique_sorted``: numpy >= 2.3 answers a plain ``np.unique(a)`` (no ``return_*``) through a hash
table, which on this project's integer ids (landmark / keyframe ids: a few hundred to tens of
thousands of clustered values) costs 20-50x a sort: 0.3 ms for 700 landmark ids, 2.4-5 ms for the
~7 k edge keyframe ids of one KITTI local BA, where ``np.sort`` takes 0.01-0.1 ms (issue 8: CPU per
frame). The sort gives the same sorted distinct values.

``isin_ids``: ``np.isin`` on integer ids picks its "sort" method when the ids' range is wide
against the array sizes (landmark ids over a whole run), and that method calls the plain
``np.unique`` above; a lookup table over the range (numpy's ``kind="table"``) answers the same
booleans in ~1/7 of the time for a few thousand KITTI landmark ids.
"""
from __future__ import annotations

import numpy as np


def unique_sorted(values) -> np.ndarray:
    """The sorted distinct values of ``values`` (flattened), as ``np.unique(values)`` gives them,
    by a sort and a neighbour comparison. For integer, bool or NaN-free float arrays (NaNs would
    each stay distinct, where ``np.unique`` merges them)."""
    a = np.sort(np.asarray(values).ravel())
    if a.size < 2:
        return a
    keep = np.empty(a.shape, bool)
    keep[0] = True
    np.not_equal(a[1:], a[:-1], out=keep[1:])
    return a[keep]


TABLE_SPAN_MAX = 1 << 22  # isin_ids: the largest id range it builds a lookup table for (4 MB of bools)


def isin_ids(values, ids) -> np.ndarray:
    """``np.isin(values, ids)`` for integer arrays, by numpy's lookup-table method when the range
    of ``ids`` is at most ``TABLE_SPAN_MAX`` (else, or for other dtypes, ``np.isin`` as it is):
    the same booleans."""
    v, i = np.asarray(values), np.asarray(ids)
    if v.size and i.size and v.dtype.kind in "iu" and i.dtype.kind in "iu" \
            and int(i.max()) - int(i.min()) <= TABLE_SPAN_MAX:
        return np.isin(v, i, kind="table")
    return np.isin(v, i)
