"""DBoW2 vocabulary files: the text layout ORB-SLAM reads (ORBvoc.txt) and DBoW2's OpenCV-YAML.

Text (ORB-SLAM2/3 ``TemplatedVocabulary::loadFromTextFile``)::

    k L scoring weighting
    parent is_leaf d0 d1 .. d31 weight        one line per node 1..n-1 (node 0 = root, implicit)

Node ids are the line numbers, so every parent precedes its children; word ids are the
leaves in node order. No newline after the last line: ORB-SLAM reads lines until EOF
and would turn a trailing empty line into a bogus node.

YAML (DBoW2 ``TemplatedVocabulary::save`` through ``cv::FileStorage``): a ``vocabulary``
map with ``k``, ``L``, ``scoringType``, ``weightingType``, ``nodes`` (``nodeId``,
``parentId``, ``weight``, ``descriptor`` as a string of byte values) and ``words``
(``wordId``, ``nodeId``). Parsed with regular expressions: one pass, no per-node calls.

Both may be gzipped (detected by the gzip magic bytes, whatever the file name).
"""
from __future__ import annotations

import gzip
import io
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.errors import InputError

_GZIP_MAGIC = b"\x1f\x8b"
_YAML_NODE = re.compile(
    r"nodeId\s*:\s*(\d+)\s*,\s*parentId\s*:\s*(\d+)\s*,\s*weight\s*:\s*([-+0-9.eEinfa]+)\s*,"
    r"\s*descriptor\s*:\s*\"([^\"]*)\"")
_YAML_WORD = re.compile(r"wordId\s*:\s*(\d+)\s*,\s*nodeId\s*:\s*(\d+)")


@dataclass
class VocabularyData:
    """The arrays of a vocabulary file, before the tree is indexed."""

    k: int
    levels: int
    scoring_index: int
    weighting_index: int
    parent: np.ndarray       # (n,) int64, parent[0] = -1
    descriptors: np.ndarray  # (n, D) uint8, row 0 (root) zeros
    is_leaf: np.ndarray      # (n,) bool
    weights: np.ndarray      # (n,) float64
    node_of_word: np.ndarray | None  # explicit word -> node (YAML); None = leaves in node order


def _read_text(path: Path) -> str:
    if not path.is_file():
        raise InputError(path, "vocabulary file not found")
    raw = path.read_bytes()
    if raw[:2] == _GZIP_MAGIC:
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError) as exc:
            raise InputError(path, f"corrupt gzip vocabulary ({exc})") from None
    try:
        return raw.decode("ascii")
    except UnicodeDecodeError:
        raise InputError(path, "not a DBoW2 text or YAML vocabulary (binary content)") from None


def _int_header(path: Path, tokens: list[str]) -> tuple[int, int, int, int]:
    try:
        k, levels, scoring, weighting = (int(t) for t in tokens)
    except ValueError:
        raise InputError(path, f"header must be 'k L scoring weighting', got {' '.join(tokens)!r}") from None
    # The ranges DBoW2's loader accepts (loadFromTextFile).
    if not (0 < k <= 20 and 1 <= levels <= 10 and 0 <= scoring <= 5 and 0 <= weighting <= 3):
        raise InputError(path, f"header out of range: k={k} L={levels} scoring={scoring} weighting={weighting}")
    return k, levels, scoring, weighting


def _parse_dbow_text(path: Path, text: str) -> VocabularyData:
    head, _, body = text.partition("\n")
    k, levels, scoring, weighting = _int_header(path, head.split())
    lines = [ln for ln in body.split("\n") if ln.strip()]
    if not lines:
        raise InputError(path, "vocabulary has a header but no nodes")
    per_line = len(lines[0].split())
    if per_line < 4:
        raise InputError(path, f"node line 2 has {per_line} fields, expected 'parent is_leaf descriptor.. weight'")
    with warnings.catch_warnings():  # numpy warns when it stops early at a bad token
        warnings.simplefilter("ignore", DeprecationWarning)
        try:
            values = np.fromstring(body, dtype=np.float64, sep=" ")  # 3x faster than split()
        except ValueError:  # a non-numeric token: the slow path below names its line
            values = np.zeros(0)
    if values.size != per_line * len(lines):  # slow path, only to name the bad line
        for i, ln in enumerate(lines):
            fields = ln.split()
            if len(fields) != per_line:
                raise InputError(path, f"node line {i + 2} has {len(fields)} fields, expected {per_line}")
            try:
                [float(f) for f in fields]
            except ValueError:
                raise InputError(path, f"node line {i + 2} has a non-numeric field") from None
        raise InputError(path, "unreadable node lines")
    table = values.reshape(len(lines), per_line)
    desc = table[:, 2:-1]
    if (desc < 0).any() or (desc > 255).any() or (desc != np.round(desc)).any():
        raise InputError(path, "descriptor fields must be byte values 0..255")
    width = per_line - 3
    return VocabularyData(
        k, levels, scoring, weighting,
        parent=np.concatenate([[-1], table[:, 0].astype(np.int64)]),
        descriptors=np.vstack([np.zeros((1, width), np.uint8), desc.astype(np.uint8)]),
        is_leaf=np.concatenate([[False], table[:, 1] != 0]),
        weights=np.concatenate([[0.0], table[:, -1]]),
        node_of_word=None)


def _yaml_int(path: Path, text: str, key: str) -> int:
    m = re.search(rf"\b{key}\s*:\s*(\d+)", text)
    if m is None:
        raise InputError(path, f"DBoW2 YAML vocabulary without '{key}'")
    return int(m.group(1))


def _parse_dbow_yaml(path: Path, text: str) -> VocabularyData:
    k, levels = _yaml_int(path, text, "k"), _yaml_int(path, text, "L")
    _int_header(path, [str(k), str(levels), str(_yaml_int(path, text, "scoringType")),
                       str(_yaml_int(path, text, "weightingType"))])
    nodes = _YAML_NODE.findall(text)
    words = _YAML_WORD.findall(text)
    if not nodes or not words:
        raise InputError(path, "DBoW2 YAML vocabulary without nodes or words")
    ids = np.array([int(n[0]) for n in nodes])
    n = int(ids.max()) + 1
    if len(np.unique(ids)) != len(ids) or len(ids) != n - 1 or ids.min() != 1:
        raise InputError(path, f"node ids must be 1..{n - 1}, each once")
    rows = [np.array(d.split(), dtype=np.int64) for _, _, _, d in nodes]
    width = len(rows[0])
    if any(len(r) != width for r in rows) or any(((r < 0) | (r > 255)).any() for r in rows):
        raise InputError(path, "node descriptors must all be the same number of byte values 0..255")
    parent = np.full(n, -1, np.int64)
    weights = np.zeros(n)
    descriptors = np.zeros((n, width), np.uint8)
    parent[ids] = [int(nd[1]) for nd in nodes]
    weights[ids] = [float(nd[2]) for nd in nodes]
    descriptors[ids] = np.vstack(rows).astype(np.uint8)
    word_table = np.array([(int(w), int(nd)) for w, nd in words], np.int64)
    node_of_word = np.full(int(word_table[:, 0].max()) + 1, -1, np.int64)
    node_of_word[word_table[:, 0]] = word_table[:, 1]
    if (node_of_word < 1).any() or (node_of_word >= n).any():
        raise InputError(path, "word table names missing nodes")
    is_leaf = np.zeros(n, bool)
    is_leaf[node_of_word] = True
    return VocabularyData(k, levels, _yaml_int(path, text, "scoringType"), _yaml_int(path, text, "weightingType"),
                          parent, descriptors, is_leaf, weights, node_of_word)


def read_vocabulary(path: str | Path) -> VocabularyData:
    """Read a DBoW2 text (ORBvoc.txt layout) or OpenCV-YAML vocabulary, gzipped or not."""
    path = Path(path)
    text = _read_text(path)
    start = text.lstrip()[:256]
    if start.startswith("%YAML") or start.startswith("vocabulary:"):
        return _parse_dbow_yaml(path, text)
    return _parse_dbow_text(path, text)


def _weight_field(weight: float, leaf: bool) -> str:
    # Inner nodes carry no weight (DBoW2 writes 0); leaves get the shortest exact repr,
    # so a save -> load round trip reproduces the float64 weights bit for bit.
    return repr(float(weight)) if leaf else "0"


def format_text(data: VocabularyData) -> str:
    """The DBoW2 text of ``data`` (no trailing newline)."""
    lines = [f"{data.k} {data.levels} {data.scoring_index} {data.weighting_index}"]
    desc = data.descriptors.tolist()
    parent = data.parent.tolist()
    leaf = data.is_leaf.tolist()
    weights = data.weights.tolist()
    for i in range(1, len(parent)):
        lines.append(f"{parent[i]} {int(leaf[i])} {' '.join(map(str, desc[i]))} {_weight_field(weights[i], leaf[i])}")
    return "\n".join(lines)


def write_text(path: str | Path, data: VocabularyData) -> None:
    """Write the DBoW2 text layout; gzipped (reproducible bytes: mtime 0) when the name ends in .gz."""
    path = Path(path)
    payload = format_text(data).encode("ascii")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".gz":
        buf = io.BytesIO()
        with gzip.GzipFile(filename="", mode="wb", fileobj=buf, mtime=0, compresslevel=9) as gz:
            gz.write(payload)
        payload = buf.getvalue()
    path.write_bytes(payload)
