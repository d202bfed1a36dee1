"""Bag-of-binary-words vocabulary: DBoW2 files, training, descent, scores on real images."""
from __future__ import annotations

import gzip
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy.frontend.features import OrbExtractor
from canopy.frontend.params import TrackingParams
from canopy.lines.features import LineDescriber, detect_segments
from canopy.lines.params import LineParams
from canopy.place import Vocabulary
from canopy.place.kmajority import build_tree
from shared.errors import InputError

DATA = Path(__file__).resolve().parents[1] / "data"
KIMERA = DATA / "kimera_lcd"
KITTI = DATA / "kitti06_snippet"
SHIPPED_ORB = DATA / "vocabulary" / "orb_k10_L4.txt.gz"
SHIPPED_LBD = DATA / "vocabulary" / "lbd_k10_L3.txt.gz"


def _grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None, path
    return img


@pytest.fixture(scope="module")
def orb() -> OrbExtractor:
    return OrbExtractor(TrackingParams())


@pytest.fixture(scope="module")
def kimera_orb(orb) -> list[np.ndarray]:
    return [orb.extract(_grey(KIMERA / f"left_img_{i}.png")).descriptors for i in range(4)]


@pytest.fixture(scope="module")
def small_trained(kimera_orb) -> Vocabulary:
    return Vocabulary.train(kimera_orb, k=6, levels=3, seed=1)


def _greedy_descent(vocab: Vocabulary, d: np.ndarray) -> int:
    """Reference descent, one descriptor, plain Python: nearest child (first on ties) per level."""
    node = 0
    while not vocab.is_leaf[node]:
        kids = [int(c) for c in vocab.children[node] if c >= 0]
        dists = [int(np.unpackbits(np.bitwise_xor(vocab.descriptors[c], d)).sum()) for c in kids]
        node = kids[int(np.argmin(dists))]
    return node


def test_kimera_dbow2_yaml_vocabulary_loads():
    v = Vocabulary.load(KIMERA / "small_voc.yml.gz")
    assert (v.k, v.levels, v.words) == (9, 3, 692)
    assert (v.weighting, v.scoring) == ("tf_idf", "l1")
    assert v.descriptor_bytes == 32
    assert (v.weights[v.node_of_word] >= 0).all() and v.weights[v.node_of_word].max() > 0
    assert v.depth.max() == 3


def test_save_load_round_trip_is_exact(tmp_path, small_trained, kimera_orb):
    for name in ("v.txt", "v.txt.gz"):
        small_trained.save(tmp_path / name)
        back = Vocabulary.load(tmp_path / name)
        assert back == small_trained
        assert back.transform(kimera_orb[0])[0] == small_trained.transform(kimera_orb[0])[0]
    # the kimera YAML vocabulary written as DBoW2 text quantises identically
    kimera = Vocabulary.load(KIMERA / "small_voc.yml.gz")
    kimera.save(tmp_path / "kimera.txt")
    again = Vocabulary.load(tmp_path / "kimera.txt")
    assert again.transform(kimera_orb[1])[0] == kimera.transform(kimera_orb[1])[0]


def test_text_output_has_the_dbow2_layout(tmp_path, small_trained):
    small_trained.save(tmp_path / "v.txt")
    text = (tmp_path / "v.txt").read_text()
    assert not text.endswith("\n")  # ORB-SLAM would read a trailing empty line as a node
    lines = text.split("\n")
    assert lines[0].split() == ["6", "3", "0", "0"]  # k L scoring(L1) weighting(TF_IDF)
    assert len(lines) == small_trained.nodes  # one line per node except the root
    for node_id, line in enumerate(lines[1:], start=1):
        f = line.split()
        assert len(f) == 2 + 32 + 1
        parent, leaf = int(f[0]), int(f[1])
        assert 0 <= parent < node_id and leaf in (0, 1)
        assert all(0 <= int(b) <= 255 for b in f[2:34])
        assert float(f[34]) >= 0 and (leaf or float(f[34]) == 0)
    # gzip output decompresses to the same text
    small_trained.save(tmp_path / "v.txt.gz")
    assert gzip.decompress((tmp_path / "v.txt.gz").read_bytes()).decode() == text


def test_words_are_the_leaves_of_the_greedy_descent(small_trained, kimera_orb):
    rng = np.random.default_rng(3)
    probe = np.vstack([kimera_orb[2][:40], rng.integers(0, 256, (20, 32), dtype=np.uint8)])
    bow, words = small_trained.transform(probe)
    expected = [_greedy_descent(small_trained, d) for d in probe]
    assert list(small_trained.node_of_word[words]) == expected
    assert abs(sum(bow.values()) - 1.0) < 1e-9


def test_descent_takes_the_first_child_on_ties_and_handles_uneven_nodes():
    """Hand-built tree (k=3): the root has 3 children, child 1 only 2 (a spare slot), child 2
    is a leaf at depth 1; probes equidistant from several children go to the first of them."""
    z = np.zeros(32, np.uint8)
    def bits(*idx):
        d = z.copy()
        for i in idx:
            d[i // 8] |= 1 << (i % 8)
        return d
    #        root      1 (inner)   2 (inner)   3 (leaf)   4,5 under 1    6,7,8 under 2
    desc = [z,         bits(0),    bits(1),    bits(2),   bits(0, 3),    bits(0, 4),
            bits(1, 5), bits(1, 6), bits(1, 7)]
    parent = [-1, 0, 0, 0, 1, 1, 2, 2, 2]
    is_leaf = [False, False, False, True, True, True, True, True, True]
    vocab = Vocabulary(3, 2, np.array(parent), np.array(desc), np.array(is_leaf), np.ones(9))
    probes = np.array([z, bits(0), bits(1), bits(2), bits(0, 1), bits(0, 3, 4), bits(1, 5, 6, 7),
                       bits(2, 3), np.full(32, 255, np.uint8)])
    got = vocab.leaf_nodes(probes).tolist()
    assert got == [_greedy_descent(vocab, d) for d in probes]
    assert got[0] == 4 and got[4] == 4  # ties at the root (1, 2, 3 equidistant), then between 4 and 5
    rng = np.random.default_rng(5)
    x = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    assert vocab.leaf_nodes(x).tolist() == [_greedy_descent(vocab, d) for d in x]
    assert vocab.leaf_nodes(np.zeros((0, 32), np.uint8)).shape == (0,)


def test_the_shipped_vocabulary_descends_kitti_descriptors_as_the_reference(orb):
    vocab = Vocabulary.load(SHIPPED_ORB)
    d = orb.extract(_grey(sorted((KITTI).rglob("*.png"))[0])).descriptors[:150]
    assert vocab.leaf_nodes(d).tolist() == [_greedy_descent(vocab, row) for row in d]


def test_training_descriptors_land_in_the_leaf_they_were_clustered_into():
    x = np.random.default_rng(0).integers(0, 256, (4000, 32), dtype=np.uint8)
    tree = build_tree(x, k=8, levels=3, seed=0, max_iterations=10)
    vocab = Vocabulary(8, 3, tree.parent, tree.descriptors, tree.is_leaf, np.ones(len(tree.parent)))
    assert np.array_equal(vocab.leaf_nodes(x), tree.leaf_of_training)
    assert vocab.words > 8 ** 2  # a real third level


def test_direct_index_nodes_are_ancestors_at_the_right_depth(small_trained, kimera_orb):
    _, words = small_trained.transform(kimera_orb[0])
    leaves = small_trained.node_of_word[words]
    for up in (1, 2):
        nodes = small_trained.node_ids(words, up)
        target = small_trained.levels - up
        assert (small_trained.depth[nodes] == np.minimum(small_trained.depth[leaves], target)).all()
        walk = leaves.copy()
        for _ in range(small_trained.levels):
            deeper = small_trained.depth[walk] > target
            walk[deeper] = small_trained.parent[walk[deeper]]
        assert np.array_equal(nodes, walk)
    assert (small_trained.node_ids(words, 5) == 0).all()


@pytest.mark.parametrize("vocab_path", [KIMERA / "small_voc.yml.gz", SHIPPED_ORB])
def test_near_duplicate_view_scores_higher_than_another_place(vocab_path, orb, kimera_orb):
    vocab = Vocabulary.load(vocab_path)
    bows = [vocab.transform(d)[0] for d in kimera_orb]
    kitti = [vocab.transform(orb.extract(_grey(KITTI / "image_l" / f"{i:06d}.png")).descriptors)[0]
             for i in (0, 1, 50)]
    score = Vocabulary.score
    # EuRoC: img_3 is 0.5 s after img_2; img_1 revisits img_0's place 98 s later
    assert score(bows[3], bows[2]) > max(score(bows[3], k) for k in kitti)
    assert score(bows[1], bows[0]) > max(score(bows[1], k) for k in kitti)
    # KITTI 06: the next frame (1 m on) against the last (60 m on, another place)
    assert score(kitti[0], kitti[1]) > score(kitti[0], kitti[2])
    assert score(bows[0], bows[0]) == pytest.approx(1.0)


def test_lbd_line_descriptors_use_the_same_vocabulary_class(tmp_path):
    params = LineParams()
    describe = LineDescriber(params)
    per_image = []
    for i in range(4):
        img = _grey(KIMERA / f"left_img_{i}.png")
        per_image.append(describe(img, detect_segments(img, params)[0]))
    vocab = Vocabulary.train(per_image, k=5, levels=2)
    bow, words = vocab.transform(per_image[0])
    # with 4 training images most words occur in all of them (idf 0), so count words used
    assert len(words) == len(per_image[0]) and len(np.unique(words)) > 10 and bow
    assert Vocabulary.score(bow, bow) == pytest.approx(1.0)
    shipped = Vocabulary.load(SHIPPED_LBD)
    assert shipped.descriptor_bytes == 32 and shipped.words > 100
    assert len(shipped.transform(per_image[0])[0]) > 5


def test_bad_input_is_refused_with_a_message_naming_it(tmp_path, small_trained):
    with pytest.raises(InputError, match="not found"):
        Vocabulary.load(tmp_path / "missing.txt")
    small_trained.save(tmp_path / "v.txt")
    lines = (tmp_path / "v.txt").read_text().split("\n")
    lines[5] = " ".join(lines[5].split()[:-3])
    (tmp_path / "bad.txt").write_text("\n".join(lines))
    with pytest.raises(InputError, match="node line 6 has 32 fields"):
        Vocabulary.load(tmp_path / "bad.txt")
    lines = (tmp_path / "v.txt").read_text().split("\n")
    fields = lines[5].split()
    fields[3] = "x"
    lines[5] = " ".join(fields)
    (tmp_path / "word.txt").write_text("\n".join(lines))
    with pytest.raises(InputError, match="node line 6 has a non-numeric field"):
        Vocabulary.load(tmp_path / "word.txt")
    (tmp_path / "head.txt").write_text("10 99 0 0\n0 1 " + " ".join(["0"] * 32) + " 1.0")
    with pytest.raises(InputError, match="header out of range"):
        Vocabulary.load(tmp_path / "head.txt")
    with pytest.raises(InputError, match=r"\(N, 32\) uint8"):
        small_trained.transform(np.zeros((3, 16), np.uint8))
    with pytest.raises(InputError, match="no descriptors"):
        Vocabulary.train(np.zeros((0, 32), np.uint8))
