"""A bag-of-binary-words vocabulary tree (Gálvez-López & Tardós 2012, the DBoW2 idea; AGRI §3.4).

Binary descriptors (ORB, or LBD from OpenCV's line_descriptor: both 32 bytes) are
quantised by descending a k-ary tree of binary centres to a leaf, the *word*. An image
becomes a sparse tf-idf vector over the words, L1-normalised, and two images are
compared by the L1 score ``s = 1 - 0.5 |v - w|_1`` in [0, 1] (DBoW2 §III). The node a
word has ``levels_up`` levels above it is DBoW2's *direct index*: features under the same
node are the only candidates for matching between two images.

Training (``Vocabulary.train``) is hierarchical k-majority (see ``kmajority.py``);
files are read and written in DBoW2's layouts (see ``dbow_format.py``), so ORB-SLAM3
loads our vocabularies and we load DBoW2's.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from canopy.place.dbow_format import VocabularyData, read_vocabulary, write_text
from canopy.place.kmajority import as_words, build_tree, idf_weights
from canopy.place.params import SCORINGS, WEIGHTINGS, VocabularyParams
from shared.errors import InputError

_ROWS_PER_CHUNK = 32768  # descriptors descended together (bounds the (rows, k, words) XOR block)


def _as_descriptor_array(descriptors, width: int | None, what: str) -> np.ndarray:
    d = np.asarray(descriptors)
    if d.ndim != 2 or d.dtype != np.uint8 or (width is not None and d.shape[1] != width):
        want = f"(N, {width})" if width is not None else "(N, bytes)"
        raise InputError(what, f"expected a {want} uint8 array, got shape {d.shape} dtype {d.dtype}")
    return np.ascontiguousarray(d)


class Vocabulary:
    """A vocabulary tree: node 0 is the root, every parent precedes its children."""

    def __init__(self, k: int, levels: int, parent: np.ndarray, descriptors: np.ndarray,
                 is_leaf: np.ndarray, weights: np.ndarray, weighting: str = "tf_idf",
                 scoring: str = "l1", node_of_word: np.ndarray | None = None,
                 source: str = "<vocabulary>"):
        self.k, self.levels = int(k), int(levels)
        self.weighting, self.scoring = weighting, scoring
        self.parent = np.asarray(parent, np.int64)
        self.descriptors = _as_descriptor_array(descriptors, None, source)
        self.is_leaf = np.asarray(is_leaf, bool)
        self.weights = np.asarray(weights, np.float64)
        n = len(self.parent)
        if not (len(self.descriptors) == len(self.is_leaf) == len(self.weights) == n) or n < 2:
            raise InputError(source, "vocabulary arrays disagree in length or hold no node below the root")
        if self.parent[0] != -1 or (self.parent[1:] < 0).any() or (self.parent[1:] >= np.arange(1, n)).any():
            raise InputError(source, "every node's parent must be an earlier node (root = node 0)")
        # children[i] = node ids of i's children in id order (DBoW2's order), -1 padded
        child = np.argsort(self.parent[1:], kind="stable") + 1
        counts = np.bincount(self.parent[1:], minlength=n)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.arange(n - 1) - first[self.parent[child]]
        self.children = np.full((n, max(int(counts.max()), 1)), -1, np.int64)
        self.children[self.parent[child], rank] = child
        if (counts[self.is_leaf] > 0).any() or (counts[~self.is_leaf] == 0).any():
            raise InputError(source, "a leaf node has children or an inner node has none")
        self.depth = np.zeros(n, np.int64)
        for _ in range(n):  # parents come first, so this settles in (tree depth + 1) passes
            new = np.concatenate([[0], self.depth[self.parent[1:]] + 1])
            if np.array_equal(new, self.depth):
                break
            self.depth = new
        self.node_of_word = (np.flatnonzero(self.is_leaf) if node_of_word is None
                             else np.asarray(node_of_word, np.int64))
        self.word_of_node = np.full(n, -1, np.int64)
        self.word_of_node[self.node_of_word] = np.arange(len(self.node_of_word))
        self._node_words = as_words(self.descriptors)
        self._build_descent_tables()

    # ------------------------------------------------------------------ properties
    @property
    def words(self) -> int:
        return len(self.node_of_word)

    @property
    def nodes(self) -> int:
        return len(self.parent)

    @property
    def descriptor_bytes(self) -> int:
        return self.descriptors.shape[1]

    def __repr__(self) -> str:
        return (f"Vocabulary(k={self.k}, levels={self.levels}, words={self.words}, nodes={self.nodes}, "
                f"{self.descriptor_bytes}-byte descriptors, {self.weighting}, {self.scoring})")

    def __eq__(self, other) -> bool:
        if not isinstance(other, Vocabulary):
            return NotImplemented
        return (self.k == other.k and self.levels == other.levels and self.weighting == other.weighting
                and self.scoring == other.scoring
                and all(np.array_equal(getattr(self, a), getattr(other, a))
                        for a in ("parent", "descriptors", "is_leaf", "weights", "node_of_word")))

    # ------------------------------------------------------------------ training
    @classmethod
    def train(cls, descriptors: np.ndarray | Sequence[np.ndarray], k: int = 10, levels: int = 5,
              seed: int = 0, *, image_index: np.ndarray | None = None, max_iterations: int = 10,
              weighting: str = "tf_idf", scoring: str = "l1") -> "Vocabulary":
        """Hierarchical k-majority tree and idf weights from training descriptors.

        ``descriptors``: one (N, D) uint8 array with ``image_index`` (N,) naming the image
        each row comes from, or a list of per-image arrays. idf needs images: without
        ``image_index`` every descriptor counts as its own image.
        """
        params = VocabularyParams(k=k, levels=levels, seed=seed, max_iterations=max_iterations,
                                  weighting=weighting, scoring=scoring)
        params.validate()
        if isinstance(descriptors, (list, tuple)):
            arrays = [_as_descriptor_array(d, None, f"descriptors[{i}]") for i, d in enumerate(descriptors)]
            image_index = np.concatenate([np.full(len(a), i) for i, a in enumerate(arrays)]) if arrays else None
            descriptors = np.vstack(arrays) if arrays else np.zeros((0, 32), np.uint8)
        x = _as_descriptor_array(descriptors, None, "training descriptors")
        if len(x) == 0:
            raise InputError("training descriptors", "no descriptors to train a vocabulary on")
        image_index = np.arange(len(x)) if image_index is None else np.asarray(image_index)
        if image_index.shape != (len(x),):
            raise InputError("image_index", f"expected shape ({len(x)},), got {image_index.shape}")
        tree = build_tree(x, params.k, params.levels, params.seed, params.max_iterations)
        node_of_word = np.flatnonzero(tree.is_leaf)
        word_of_node = np.full(len(tree.parent), -1, np.int64)
        word_of_node[node_of_word] = np.arange(len(node_of_word))
        weights = np.zeros(len(tree.parent))
        if params.weighting in ("tf_idf", "idf"):
            weights[node_of_word] = idf_weights(word_of_node[tree.leaf_of_training], image_index,
                                                len(node_of_word))
        else:  # tf and binary weigh every word 1 (DBoW2 setNodeWeights)
            weights[node_of_word] = 1.0
        return cls(params.k, params.levels, tree.parent, tree.descriptors, tree.is_leaf, weights,
                   params.weighting, params.scoring)

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path) -> None:
        """DBoW2 text layout (ORB-SLAM's ORBvoc.txt), gzipped if the name ends in .gz."""
        write_text(path, VocabularyData(self.k, self.levels, SCORINGS.index(self.scoring),
                                        WEIGHTINGS.index(self.weighting), self.parent, self.descriptors,
                                        self.is_leaf, self.weights, None))

    @classmethod
    def load(cls, path: str | Path) -> "Vocabulary":
        """A DBoW2 text or OpenCV-YAML vocabulary (either may be gzipped)."""
        d = read_vocabulary(path)
        return cls(d.k, d.levels, d.parent, d.descriptors, d.is_leaf, d.weights,
                   WEIGHTINGS[d.weighting_index], SCORINGS[d.scoring_index], d.node_of_word, str(path))

    # ------------------------------------------------------------------ use
    def _build_descent_tables(self) -> None:
        """Per inner node, its children's descriptors laid out for ``leaf_nodes``: one row of
        (word, child) -> the child's descriptor word, so one row gather per descriptor and level
        gives every child (issue 8: the per-level (rows, k, words) fancy gather and the
        reductions over its short axes cost ~6 ms per 2000-descriptor KITTI keyframe).

        A node with fewer than k children repeats its first child in the spare slots: a repeat
        is never strictly nearer than the first child itself, so with "first on ties" the pick
        is the same as with the slots left out."""
        inner = np.flatnonzero(~self.is_leaf)
        self._inner_row = np.full(self.nodes, -1, np.int64)
        self._inner_row[inner] = np.arange(len(inner))
        kids = self.children[inner]
        kids = np.where(kids < 0, kids[:, :1], kids)   # every inner node has a first child
        self._row_children = np.ascontiguousarray(kids)
        per_word = self._node_words[kids]               # (inner, k, words)
        self._row_words = np.ascontiguousarray(per_word.transpose(0, 2, 1).reshape(len(inner), -1))
        k = kids.shape[1]
        shift = max(int(k - 1).bit_length(), 1)
        max_dist = 8 * self.descriptor_bytes
        self._key_shift = shift
        self._key_dtype = np.uint16 if (max_dist << shift) + k < 2 ** 16 else np.uint32
        self._key_slot = np.arange(k, dtype=self._key_dtype)[:, None]

    def leaf_nodes(self, descriptors: np.ndarray) -> np.ndarray:
        """The leaf node each descriptor reaches by greedy descent (nearest child at every
        level, first on ties, as DBoW2's ``transform``).

        All descriptors descend together, one level per step: the children's descriptor
        words of each descriptor's node are gathered as one row, XORed with the descriptor
        (repeated once per child), popcounted; the Hamming distance of each child is the sum
        of its words' counts, and the nearest child, first on ties, is the minimum of
        (distance << bits) | slot taken across the children (a reduction along the long
        axis, as the counts are transposed to (slot, descriptor))."""
        x = _as_descriptor_array(descriptors, self.descriptor_bytes, "descriptors")
        node = np.zeros(len(x), np.int64)
        if not len(x) or self.is_leaf[0]:
            return node
        x_words = as_words(x)
        k, n_words = self._row_children.shape[1], x_words.shape[1]
        mask = (1 << self._key_shift) - 1
        for s in range(0, len(x), _ROWS_PER_CHUNK):
            active = np.arange(s, min(s + _ROWS_PER_CHUNK, len(x)))
            x_rep = np.repeat(x_words[active], k, axis=1)   # (rows, words * k), word-major like the table
            while active.size:
                rows = np.take(self._inner_row, node[active])
                block = np.take(self._row_words, rows, axis=0)
                block ^= x_rep
                counts = np.bitwise_count(block).T.astype(self._key_dtype)   # (words * k, rows)
                key = counts[:k].copy()
                for w in range(1, n_words):
                    key += counts[w * k:(w + 1) * k]
                key <<= self._key_shift
                key |= self._key_slot
                slot = (np.minimum.reduce(key, axis=0) & mask).astype(np.int64)
                reached = np.take(self._row_children, rows, axis=0)[np.arange(len(rows)), slot]
                node[active] = reached
                inner = ~self.is_leaf[reached]
                if not inner.all():
                    active, x_rep = active[inner], x_rep[inner]
        return node

    def transform(self, descriptors: np.ndarray) -> tuple[dict[int, float], np.ndarray]:
        """(bag-of-words vector {word id: weight}, word id of each descriptor).

        tf-idf: a word's weight is idf_i times its count in the image (the 1/n_d term of
        tf vanishes in the normalisation); words of zero weight are left out, as in DBoW2.
        """
        node = self.leaf_nodes(descriptors)
        word_ids = self.word_of_node[node]
        if len(node) == 0:
            return {}, word_ids
        w = self.weights[node]
        keep = w > 0
        uniq, inverse = np.unique(word_ids[keep], return_inverse=True)
        if self.weighting == "binary":
            values = self.weights[self.node_of_word[uniq]]
        else:
            values = np.bincount(inverse, weights=w[keep], minlength=len(uniq))
        if self.scoring == "l1":
            norm = np.abs(values).sum()
        elif self.scoring == "l2":
            norm = np.sqrt((values * values).sum())
        else:
            norm = 1.0
        if norm > 0:
            values = values / norm
        return dict(zip(uniq.tolist(), values.tolist())), word_ids

    def node_ids(self, word_ids: np.ndarray, levels_up: int) -> np.ndarray:
        """DBoW2's direct index: the ancestor of each word at depth ``levels - levels_up``
        (depth 1 = the root's children); a word shallower than that is its own node, and
        ``levels_up >= levels`` gives the root."""
        word_ids = np.asarray(word_ids, np.int64)
        if word_ids.size and (word_ids.min() < 0 or word_ids.max() >= self.words):
            raise InputError("word_ids", f"word ids must be in [0, {self.words})")
        node = self.node_of_word[word_ids]
        target = max(self.levels - int(levels_up), 0)
        while True:
            up = self.depth[node] > target
            if not up.any():
                return node
            node[up] = self.parent[node[up]]

    @staticmethod
    def score(a: dict[int, float], b: dict[int, float]) -> float:
        """DBoW2's L1 score of two L1-normalised vectors: 1 - 0.5 |a - b|_1, in [0, 1].

        Summed over shared words only (|a_i| + |b_i| - |a_i - b_i|), which is the same
        for normalised vectors and gives 0 for an empty one.
        """
        if len(a) > len(b):
            a, b = b, a
        total = 0.0
        for word, va in a.items():
            vb = b.get(word)
            if vb is not None:
                total += abs(va) + abs(vb) - abs(va - vb)
        return min(1.0, 0.5 * total)  # rounding can exceed 1 by an ulp or so
