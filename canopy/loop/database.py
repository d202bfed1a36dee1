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


class KeyframeDatabase:
    """``add`` / ``remove`` keyframes, ``query`` by BoW vector; ``score`` between two stored ones."""

    def __init__(self):
        self._entries: dict[int, _Entry] = {}
        self._index: dict[int, dict[int, float]] = {}       # point word -> {keyframe: weight}
        self._line_index: dict[int, dict[int, float]] = {}  # line word -> {keyframe: weight}

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
        for w, v in entry.bow.items():
            self._index.setdefault(int(w), {})[kf] = float(v)
        for w, v in entry.line_bow.items():
            self._line_index.setdefault(int(w), {})[kf] = float(v)

    def remove(self, kf: int) -> None:
        entry = self._entries.pop(kf, None)
        if entry is None:
            return
        for index, bow in ((self._index, entry.bow), (self._line_index, entry.line_bow)):
            for w in bow:
                posting = index.get(w)
                if posting is not None:
                    posting.pop(kf, None)
                    if not posting:
                        del index[w]

    def bow(self, kf: int) -> Bow:
        return self._entries[kf].bow

    def score(self, kf_a: int, kf_b: int) -> float:
        """Combined score between two stored keyframes."""
        a, b = self._entries[kf_a], self._entries[kf_b]
        return combined_score(l1_score(a.bow, b.bow), l1_score(a.line_bow, b.line_bow), a.stats, b.stats)

    def score_with(self, bow: Bow, line_bow: Bow | None, stats: FeatureStats | None, kf: int) -> float:
        """Combined score between a query vector and stored keyframe ``kf``."""
        e = self._entries[kf]
        stats = stats or FeatureStats(n_points=len(bow))
        return combined_score(l1_score(bow, e.bow), l1_score(line_bow or {}, e.line_bow), stats, e.stats)

    @staticmethod
    def _accumulate(index: dict[int, dict[int, float]], bow: Bow, exclude) -> tuple[dict[int, float], dict[int, int]]:
        """Sum of |a|+|b|-|a-b| per keyframe over shared words (halved by the caller), and
        the number of shared words, touching only the postings of the query's words."""
        acc: dict[int, float] = {}
        common: dict[int, int] = {}
        for w, va in bow.items():
            posting = index.get(w)
            if not posting:
                continue
            for kf, vb in posting.items():
                if kf in exclude:
                    continue
                acc[kf] = acc.get(kf, 0.0) + abs(va) + abs(vb) - abs(va - vb)
                common[kf] = common.get(kf, 0) + 1
        return acc, common

    def query(self, bow: Bow, line_bow: Bow | None = None, stats: FeatureStats | None = None,
              exclude=frozenset(), min_score: float = 0.0, min_common_words_ratio: float = 0.0) -> list[Candidate]:
        """Stored keyframes sharing words with the query, best first (ORB-SLAM
        DetectLoopCandidates steps 1-2): only keyframes sharing at least
        ``min_common_words_ratio`` x the most words any keyframe shares, and scoring at
        least ``min_score`` (ORB-SLAM: the lowest score of the query's covisible
        neighbours, so that a candidate looks at least as alike as the views next to it)."""
        stats = stats or FeatureStats(n_points=len(bow))
        acc, common = self._accumulate(self._index, bow, exclude)
        line_acc: dict[int, float] = {}
        if line_bow:
            line_acc, line_common = self._accumulate(self._line_index, line_bow, exclude)
            for kf in line_common:
                common.setdefault(kf, 0)
        if not common:
            return []
        max_common = max(common.values())
        out = []
        for kf, n_common in common.items():
            if n_common < min_common_words_ratio * max_common:
                continue
            s = combined_score(0.5 * acc.get(kf, 0.0), 0.5 * line_acc.get(kf, 0.0), stats, self._entries[kf].stats)
            if s >= min_score:
                out.append(Candidate(kf, s, n_common))
        out.sort(key=lambda c: (-c.score, c.keyframe))
        return out
