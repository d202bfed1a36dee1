"""Hierarchical k-majority clustering of binary descriptors (the vocabulary tree of DBoW2).

Gálvez-López & Tardós, "Bags of Binary Words for Fast Place Recognition in Image
Sequences" (T-RO 2012), §III: the tree is built by running k-medians on the training
descriptors, then again on the descriptors of every cluster, down to ``levels``; on
binary strings the median is the bitwise majority and the distance is Hamming. Seeds are
chosen by k-means++ (Arthur & Vassilvitskii 2007) with Hamming distance. A cluster of
one descriptor, or of at most k descriptors (one child each), stops early, as in DBoW2.

Pure numpy: ``np.bitwise_count`` on 64-bit views of the descriptors gives Hamming
distances without unpacking the bits.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

_ROWS_PER_CHUNK = 32768  # rows of the (rows, m, words) XOR block kept in memory at once


def as_words(descriptors: np.ndarray) -> np.ndarray:
    """The descriptors viewed as uint64 words (uint8 if the row length is not a multiple of 8)."""
    d = np.ascontiguousarray(descriptors, np.uint8)
    return d.view(np.uint64) if d.shape[1] % 8 == 0 else d


def hamming(x_words: np.ndarray, c_words: np.ndarray) -> np.ndarray:
    """(n, m) int32 Hamming distances between rows of ``x_words`` and ``c_words`` (see ``as_words``)."""
    out = np.empty((len(x_words), len(c_words)), np.int32)
    for s in range(0, len(x_words), _ROWS_PER_CHUNK):
        block = x_words[s:s + _ROWS_PER_CHUNK, None, :] ^ c_words[None]
        out[s:s + _ROWS_PER_CHUNK] = np.bitwise_count(block).sum(2, dtype=np.int32)
    return out


def bit_majority(descriptors: np.ndarray, labels: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Bitwise majority of each cluster (the binary median); an empty cluster keeps its centre.

    A bit that is set in exactly half the members is set (ties go to 1).
    """
    out = centres.copy()
    for c in range(len(centres)):
        members = descriptors[labels == c]
        if len(members):
            ones = np.unpackbits(members, axis=1).sum(0, dtype=np.int64)
            out[c] = np.packbits(2 * ones >= len(members))
    return out


def kmeanspp_seeds(x_words: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of at most k seeds: the first uniform, the next ones with probability ∝ D(x)²
    (k-means++); stops early when every descriptor equals a seed."""
    n = len(x_words)
    seeds = [int(rng.integers(n))]
    nearest = hamming(x_words, x_words[seeds[:1]])[:, 0].astype(np.float64)
    while len(seeds) < k:
        w = nearest * nearest
        total = w.sum()
        if total == 0.0:
            break
        seeds.append(int(rng.choice(n, p=w / total)))
        nearest = np.minimum(nearest, hamming(x_words, x_words[seeds[-1:]])[:, 0])
    return np.asarray(seeds)


def kmajority(descriptors: np.ndarray, k: int, rng: np.random.Generator,
              max_iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Cluster one node's descriptors: (centres (m, D) uint8 with m <= k, label of each row).

    The labels returned are always the nearest centre (first one on ties), so a training
    descriptor lands in the same child as a tree descent would send it.
    """
    n = len(descriptors)
    if n <= k:  # DBoW2's trivial case: one child per descriptor
        return descriptors.copy(), np.arange(n)
    x_words = as_words(descriptors)
    centres = descriptors[kmeanspp_seeds(x_words, k, rng)]
    labels = hamming(x_words, as_words(centres)).argmin(1)
    for _ in range(max_iterations):
        centres = bit_majority(descriptors, labels, centres)
        new_labels = hamming(x_words, as_words(centres)).argmin(1)
        if np.array_equal(new_labels, labels):
            break
        labels = new_labels
    used = np.bincount(labels, minlength=len(centres)) > 0
    if not used.all():  # drop empty clusters, renumber labels in order
        remap = np.cumsum(used) - 1
        centres, labels = centres[used], remap[labels]
    return centres, labels


@dataclass
class Tree:
    """A vocabulary tree in breadth-first node order (node 0 = root, parents before children)."""

    parent: np.ndarray          # (n_nodes,) int64, -1 for the root
    descriptors: np.ndarray     # (n_nodes, D) uint8, zeros for the root
    is_leaf: np.ndarray         # (n_nodes,) bool
    leaf_of_training: np.ndarray  # (N,) node id of the leaf each training descriptor ended in


def build_tree(descriptors: np.ndarray, k: int, levels: int, seed: int, max_iterations: int) -> Tree:
    """Hierarchical k-majority (breadth first), keeping each node's training rows contiguous.

    ``order`` is a permutation of the training rows; every node owns a segment of it and
    its children own consecutive sub-segments, so no per-node index lists are kept.
    """
    n, width = descriptors.shape
    rng = np.random.default_rng(seed)
    order = np.arange(n)
    parent, centre, leaf, segment, depth = [-1], [np.zeros(width, np.uint8)], [False], [(0, n)], [0]
    queue = deque([0])
    while queue:
        node = queue.popleft()
        start, end = segment[node]
        if node != 0 and (depth[node] == levels or end - start <= 1):
            leaf[node] = True
            continue
        rows = order[start:end]
        centres, labels = kmajority(descriptors[rows], k, rng, max_iterations)
        order[start:end] = rows[np.argsort(labels, kind="stable")]
        counts = np.bincount(labels, minlength=len(centres))
        child_start = start + np.concatenate([[0], np.cumsum(counts)[:-1]])
        for c in range(len(centres)):
            parent.append(node)
            centre.append(centres[c])
            leaf.append(False)
            segment.append((int(child_start[c]), int(child_start[c] + counts[c])))
            depth.append(depth[node] + 1)
            queue.append(len(parent) - 1)
    leaf_of_training = np.empty(n, np.int64)
    for node in np.flatnonzero(leaf):
        s, e = segment[node]
        leaf_of_training[order[s:e]] = node
    return Tree(np.asarray(parent, np.int64), np.asarray(centre, np.uint8),
                np.asarray(leaf, bool), leaf_of_training)


def idf_weights(word_of_training: np.ndarray, image_of_training: np.ndarray, n_words: int) -> np.ndarray:
    """idf_i = log(N / n_i): N training images, n_i of them holding word i (tf-idf of Gálvez-López & Tardós 2012 §III)."""
    images, image_rank = np.unique(image_of_training, return_inverse=True)
    pairs = np.unique(word_of_training.astype(np.int64) * len(images) + image_rank)
    holding = np.bincount(pairs // len(images), minlength=n_words)
    with np.errstate(divide="ignore"):
        idf = np.log(len(images) / holding.astype(np.float64))
    idf[holding == 0] = 0.0
    return idf
