"""Training descriptors for a vocabulary: images from folders, ORB or LBD descriptors per image.

Used by ``tools/train_vocabulary.py`` (the shipped vocabularies) and the peer benchmark
(the larger vocabulary ORB-SLAM3 needs, trained once into ``cache/vocabulary/``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from canopy.frontend.features import OrbExtractor
from canopy.frontend.params import TrackingParams
from canopy.lines.features import LineDescriber, detect_segments
from canopy.lines.params import LineParams
from canopy.place.vocabulary import Vocabulary
from shared.errors import InputError

DESCRIPTOR_KINDS = ("orb", "lbd")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".bmp")


@dataclass(frozen=True)
class ImageSource:
    """A folder of images, every ``stride``-th one (sorted by name) used."""

    folder: Path
    stride: int = 1

    @staticmethod
    def parse(text: str) -> "ImageSource":
        """``FOLDER`` or ``FOLDER:STRIDE``."""
        folder, _, stride = text.rpartition(":") if text.rpartition(":")[2].isdigit() else (text, "", "1")
        if int(stride) < 1:
            raise InputError(text, "stride must be >= 1")
        return ImageSource(Path(folder), int(stride))

    def images(self) -> list[Path]:
        if not self.folder.is_dir():
            raise InputError(self.folder, "image folder not found")
        files = sorted(p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(self.folder, "no images in folder")
        return files[:: self.stride]


@dataclass
class TrainingSet:
    descriptors: np.ndarray                      # (N, 32) uint8
    image_index: np.ndarray                      # (N,) image each row came from
    images: list[Path] = field(default_factory=list)
    extract_s: float = 0.0


class DescriptorExtractor:
    """ORB (Canopy's grid-bucketed frontend extractor) or LBD (Canopy's line detector + LBD)."""

    def __init__(self, kind: str, tracking: TrackingParams | None = None, lines: LineParams | None = None):
        if kind not in DESCRIPTOR_KINDS:
            raise InputError("--kind", f"unknown descriptor kind {kind!r}; choose one of {DESCRIPTOR_KINDS}")
        self.kind = kind
        self.line_params = lines or LineParams()
        self._orb = OrbExtractor(tracking or TrackingParams()) if kind == "orb" else None
        self._lbd = LineDescriber(self.line_params) if kind == "lbd" else None

    def __call__(self, grey: np.ndarray) -> np.ndarray:
        if self._orb is not None:
            return self._orb.extract(grey).descriptors
        segs, _ = detect_segments(grey, self.line_params)
        return self._lbd(grey, segs)


def collect_descriptors(sources: list[ImageSource], kind: str, max_per_image: int | None = None,
                        seed: int = 0) -> TrainingSet:
    """Descriptors of every image of ``sources``; at most ``max_per_image`` per image (random subset)."""
    extractor = DescriptorExtractor(kind)
    rng = np.random.default_rng(seed)
    chunks, owners, images = [], [], []
    t0 = time.perf_counter()
    for source in sources:
        for path in source.images():
            grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if grey is None:
                raise InputError(path, "cannot read image")
            d = extractor(grey)
            if max_per_image is not None and len(d) > max_per_image:
                d = d[np.sort(rng.choice(len(d), max_per_image, replace=False))]
            if len(d):
                chunks.append(d)
                owners.append(np.full(len(d), len(images)))
            images.append(path)
    if not chunks:
        raise InputError(", ".join(str(s.folder) for s in sources), f"no {kind} descriptors found in the images")
    return TrainingSet(np.vstack(chunks), np.concatenate(owners), images, time.perf_counter() - t0)


def train_from_images(sources: list[ImageSource], kind: str = "orb", k: int = 10, levels: int = 4,
                      seed: int = 0, max_per_image: int | None = None,
                      max_iterations: int = 10) -> tuple[Vocabulary, dict]:
    """Train on the images of ``sources``; returns the vocabulary and a provenance record."""
    data = collect_descriptors(sources, kind, max_per_image, seed)
    t0 = time.perf_counter()
    vocab = Vocabulary.train(data.descriptors, k=k, levels=levels, seed=seed, image_index=data.image_index,
                             max_iterations=max_iterations)
    train_s = time.perf_counter() - t0
    record = {
        "kind": kind, "k": k, "levels": levels, "seed": seed, "max_iterations": max_iterations,
        "max_per_image": max_per_image, "words": vocab.words, "nodes": vocab.nodes,
        "images": len(data.images), "descriptors": int(len(data.descriptors)),
        "sources": [{"folder": str(s.folder), "stride": s.stride} for s in sources],
        "extract_s": round(data.extract_s, 1), "train_s": round(train_s, 1),
    }
    return vocab, record
