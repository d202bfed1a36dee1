"""Inverted-index keyframe database for place recognition (AGRI §3.4.1; DBoW2 / ORB-SLAM).

Each keyframe is stored as its bag-of-words vector (word id -> tf-idf weight, L1
normalised, as the vocabulary's ``transform`` gives it). The inverted index maps a word
to the keyframes containing it, so a query only touches keyframes sharing a word with it
(Gálvez-López & Tardós 2012, §IV). Scores are DBoW2's L1 score

    s(a, b) = 1 - 0.5 * |a - b|_1 = 0.5 * sum_w (|a_w| + |b_w| - |a_w - b_w|),   in [0, 1],

accumulated word by word over the inverted index. With lines (AGRI detects on ORB and
LSD/LBD words "parallelly"), the point and line scores are combined as PL-SLAM does
(Gomez-Ojeda et al. 2019, §VI-A): each score is weighted by the share of that feature
type in the image, by count and by spread, so a textureless view leans on its lines.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.errors import CanopyError

Bow = dict[int, float]


def l1_score(a: Bow, b: Bow) -> float:
    """DBoW2 L1 score of two L1-normalised BoW vectors (1: identical, 0: no word in common)."""
    if len(a) > len(b):
        a, b = b, a
    s = 0.0
    for w, va in a.items():
        vb = b.get(w)
        if vb is not None:
            s += abs(va) + abs(vb) - abs(va - vb)
    return 0.5 * s


def image_spread(xy: np.ndarray) -> float:
    """Spread of feature positions (points, or segment midpoints): sqrt of the mean of the
    two coordinate variances, in pixels. PL-SLAM's dispersion term."""
    xy = np.asarray(xy, float).reshape(-1, 2)
    if len(xy) < 2:
        return 0.0
    return float(np.sqrt(xy.var(axis=0).mean()))


@dataclass(frozen=True)
class FeatureStats:
    """Counts and spreads of a keyframe's points and lines (weights of the combined score)."""
    n_points: int = 0
    n_lines: int = 0
    spread_points: float = 0.0
    spread_lines: float = 0.0

    @staticmethod
    def of(points_uv: np.ndarray, line_segments: np.ndarray | None = None) -> "FeatureStats":
        segs = np.zeros((0, 4)) if line_segments is None else np.asarray(line_segments, float).reshape(-1, 4)
        mid = 0.5 * (segs[:, :2] + segs[:, 2:])
        return FeatureStats(len(points_uv), len(segs), image_spread(points_uv), image_spread(mid))


def combined_score(s_points: float, s_lines: float, a: FeatureStats, b: FeatureStats) -> float:
    """PL-SLAM's point+line similarity: s = w_p s_p + w_l s_l with
    w_p = (n_p / (n_p + n_l) + d_p / (d_p + d_l)) / 2 and w_l = 1 - w_p, the counts n and
    spreads d being those of the two images together."""
    n_p, n_l = a.n_points + b.n_points, a.n_lines + b.n_lines
    d_p, d_l = a.spread_points + b.spread_points, a.spread_lines + b.spread_lines
    if n_l == 0 or d_l == 0:
        return s_points
    if n_p == 0 or d_p == 0:
        return s_lines
    w_p = 0.5 * (n_p / (n_p + n_l) + d_p / (d_p + d_l))
    return w_p * s_points + (1.0 - w_p) * s_lines


@dataclass
class _Entry:
    bow: Bow
    line_bow: Bow
    stats: FeatureStats


@dataclass(frozen=True)
class Candidate:
    keyframe: int
    score: float          # combined L1 score with the query
    common_words: int     # point words shared with the query


def _as_arrays(bow: Bow) -> tuple[np.ndarray, np.ndarray]:
    """A BoW vector as (word ids sorted, weights)."""
    if not bow:
        return np.zeros(0, np.int64), np.zeros(0, np.float64)
    w = np.fromiter(bow.keys(), np.int64, len(bow))
    v = np.fromiter(bow.values(), np.float64, len(bow))
    order = np.argsort(w, kind="stable")
    return w[order], v[order]


class InvertedIndex:
    """Word -> (keyframe, weight) postings as flat arrays sorted by word, so a query gathers the
    postings of all its words at once (DBoW2's inverted file, vectorised): the loop closer queries
    with every keyframe, and a dict-of-dicts walk in Python cost ~70 ms per query on a
    400-keyframe map (issue 10: the loop closer's CPU competes with tracking on 2 cores).

    New keyframes go to a tail that is merged into the sorted arrays once it holds a quarter as
    many postings (amortised O(n log n)); removed keyframes are masked, then dropped at a merge."""

    MIN_MERGE = 4096

    def __init__(self):
        self._words = np.zeros(0, np.int64)
        self._kfs = np.zeros(0, np.int64)
        self._vals = np.zeros(0, np.float64)
        self._tail: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._tail_len = 0
        self._removed: set[int] = set()

    def add(self, kf: int, words: np.ndarray, vals: np.ndarray) -> None:
        self._removed.discard(kf)
        if len(words):
            self._tail.append((words, np.full(len(words), kf, np.int64), vals))
            self._tail_len += len(words)
        if self._tail_len > max(self.MIN_MERGE, len(self._words) // 4):
            self._merge()

    def remove(self, kf: int) -> None:
        self._removed.add(int(kf))

    def _merge(self) -> None:
        parts = [(self._words, self._kfs, self._vals), *self._tail]
        w, k, v = (np.concatenate([p[i] for p in parts]) for i in range(3))
        if self._removed:
            keep = ~np.isin(k, np.fromiter(self._removed, np.int64, len(self._removed)))
            w, k, v = w[keep], k[keep], v[keep]
            self._removed = set()
        order = np.argsort(w, kind="stable")   # stable: postings of a word stay in insertion order
        self._words, self._kfs, self._vals = w[order], k[order], v[order]
        self._tail, self._tail_len = [], 0

    def accumulate(self, q_words: np.ndarray, q_vals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every stored keyframe sharing a word with the query (sorted ``q_words``): its id,
        sum over shared words of |a|+|b|-|a-b| (twice the L1 score's sum, halved by the caller)
        and the number of shared words."""
        empty = (np.zeros(0, np.int64), np.zeros(0, np.float64), np.zeros(0, np.int64))
        if not len(q_words):
            return empty
        lo = np.searchsorted(self._words, q_words, side="left")
        hi = np.searchsorted(self._words, q_words, side="right")
        counts = hi - lo
        total = int(counts.sum())
        pos = np.repeat(lo - np.cumsum(counts) + counts, counts) + np.arange(total)
        kfs, vb, va = self._kfs[pos], self._vals[pos], np.repeat(q_vals, counts)
        if self._tail:
            tw, tk, tv = (np.concatenate([p[i] for p in self._tail]) for i in range(3))
            j = np.clip(np.searchsorted(q_words, tw), 0, len(q_words) - 1)
            hit = q_words[j] == tw
            kfs, vb, va = np.r_[kfs, tk[hit]], np.r_[vb, tv[hit]], np.r_[va, q_vals[j[hit]]]
        if self._removed:
            keep = ~np.isin(kfs, np.fromiter(self._removed, np.int64, len(self._removed)))
            kfs, vb, va = kfs[keep], vb[keep], va[keep]
        if not len(kfs):
            return empty
        terms = np.abs(va) + np.abs(vb) - np.abs(va - vb)
        top = int(kfs.max())
        if kfs.min() >= 0 and top <= 64 * len(kfs) + 4096:
            # keyframe indices are small non-negative ints: bins by index directly. bincount adds
            # each bin's terms in array order, as over np.unique's inverse, so the sums are the same
            # bits without sorting the ~10^4-10^5 postings (issue 8: the loop closer's CPU)
            common = np.bincount(kfs, minlength=top + 1)
            ids = np.flatnonzero(common)
            return ids.astype(np.int64, copy=False), np.bincount(kfs, weights=terms, minlength=top + 1)[ids], common[ids]
        ids, inv = np.unique(kfs, return_inverse=True)
        return ids, np.bincount(inv, weights=terms, minlength=len(ids)), np.bincount(inv, minlength=len(ids))


class KeyframeDatabase:
    """``add`` / ``remove`` keyframes, ``query`` by BoW vector; ``score`` between two stored ones."""

    def __init__(self):
        self._entries: dict[int, _Entry] = {}
        self._index = InvertedIndex()        # point words
        self._line_index = InvertedIndex()   # line words

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, kf: int) -> bool:
        return kf in self._entries

    def keyframes(self) -> list[int]:
        return sorted(self._entries)

    def add(self, kf: int, bow: Bow, line_bow: Bow | None = None, stats: FeatureStats | None = None) -> None:
        if kf in self._entries:
            raise CanopyError(f"keyframe database: keyframe {kf} is already stored")
        entry = _Entry(dict(bow), dict(line_bow or {}), stats or FeatureStats(n_points=len(bow)))
        self._entries[kf] = entry
        self._index.add(kf, *_as_arrays(entry.bow))
        self._line_index.add(kf, *_as_arrays(entry.line_bow))

    def remove(self, kf: int) -> None:
        if self._entries.pop(kf, None) is None:
            return
        self._index.remove(kf)
        self._line_index.remove(kf)

    def bow(self, kf: int) -> Bow:
        return self._entries[kf].bow

    def scores(self, bow: Bow, line_bow: Bow | None = None, stats: FeatureStats | None = None) -> dict[int, tuple[float, int]]:
        """Combined score and shared point words of the query with every stored keyframe that
        shares a word with it (one pass over the inverted index; others score 0)."""
        stats = stats or FeatureStats(n_points=len(bow))
        ids, acc, common = self._index.accumulate(*_as_arrays(bow))
        out = {int(k): [0.5 * a, int(c)] for k, a, c in zip(ids.tolist(), acc.tolist(), common.tolist())}
        line = {}
        if line_bow:
            l_ids, l_acc, _ = self._line_index.accumulate(*_as_arrays(line_bow))
            line = dict(zip(l_ids.tolist(), (0.5 * l_acc).tolist()))
            for k in line:
                out.setdefault(int(k), [0.0, 0])
        return {k: (combined_score(sp, line.get(k, 0.0), stats, self._entries[k].stats), c)
                for k, (sp, c) in out.items()}

    def query(self, bow: Bow, line_bow: Bow | None = None, stats: FeatureStats | None = None,
              exclude=frozenset(), min_score: float = 0.0, min_common_words_ratio: float = 0.0,
              scores: dict[int, tuple[float, int]] | None = None) -> list[Candidate]:
        """Stored keyframes sharing words with the query, best first (ORB-SLAM
        DetectLoopCandidates steps 1-2): only keyframes sharing at least
        ``min_common_words_ratio`` x the most words any keyframe shares, and scoring at
        least ``min_score`` (ORB-SLAM: the lowest score of the query's covisible
        neighbours, so that a candidate looks at least as alike as the views next to it).
        ``scores``: this query's ``scores(...)`` when the caller already has them."""
        if scores is None:
            scores = self.scores(bow, line_bow, stats)
        common = {k: v for k, v in scores.items() if k not in exclude}
        if not common:
            return []
        max_common = max(c for _, c in common.values())
        out = [Candidate(k, s, c) for k, (s, c) in common.items()
               if c >= min_common_words_ratio * max_common and s >= min_score]
        out.sort(key=lambda c: (-c.score, c.keyframe))
        return out
