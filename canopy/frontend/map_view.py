"""Tracking's copy of the local map (the landmark store tracking reads).

``MapView`` holds arrays of landmark ids, world positions and ORB descriptors (plus the
descriptors as 64-bit words for fast Hamming distances). The tracker merges the last
``LocalMapUpdate`` from local mapping with the provisional landmarks of keyframes local
mapping has not acknowledged yet (``merge_views``), so lockstep and asynchronous runs see
the same landmarks in the same order.
"""
from __future__ import annotations

import numpy as np

from canopy.frontend.matching import as_words


class MapView:
    """Tracking's copy of the local map: arrays of landmark ids, positions, descriptors."""

    def __init__(self):
        self.ids = np.zeros(0, np.int64)
        self.pos = np.zeros((0, 3))
        self.desc = np.zeros((0, 32), np.uint8)
        self.words = as_words(self.desc)

    def set(self, ids, pos, desc):
        self.ids = np.asarray(ids, np.int64)
        self.pos = np.asarray(pos, np.float64).reshape(-1, 3)
        self.desc = np.ascontiguousarray(desc, np.uint8).reshape(-1, 32)
        self.words = as_words(self.desc)



def merge_views(base: MapView, provisional: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]],
                out: MapView) -> MapView:
    """``out`` := ``base`` followed by the provisional landmarks in keyframe order, each id once
    (the first occurrence wins: the mapped position beats the provisional one)."""
    parts = [(base.ids, base.pos, base.desc)] + [provisional[k] for k in sorted(provisional)]
    ids = np.concatenate([p[0] for p in parts])
    pos = np.concatenate([p[1] for p in parts])
    desc = np.concatenate([p[2] for p in parts])
    _, first = np.unique(ids, return_index=True)
    first = np.sort(first)
    out.set(ids[first], pos[first], desc[first])
    return out


def seen_counts(seen: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ORB-SLAM's visible / found counters of the frames since the last keyframe: ``seen`` holds,
    per tracked frame, the ids of the local-map landmarks in view and whether each was matched
    (1.0) or not; returns (unique ids, times visible, times found) for ``KeyframeData.seen_*``."""
    if not seen:
        return np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros(0, np.int32)
    ids = np.concatenate([s[0] for s in seen])
    found = np.concatenate([s[1] for s in seen])
    uids, inv = np.unique(ids, return_inverse=True)
    return (uids, np.bincount(inv, minlength=len(uids)).astype(np.int32),
            np.bincount(inv, weights=found, minlength=len(uids)).astype(np.int32))
