"""Train a bag-of-binary-words vocabulary (DBoW2 text format) on real and generated images.

    # the shipped ORB vocabulary (k=10, L=4) and LBD vocabulary (k=10, L=3)
    CANOPY_CACHE_DIR=/work/cache python tools/train_vocabulary.py --kind orb --k 10 --levels 4 \
        --out data/vocabulary/orb_k10_L4.txt.gz
    CANOPY_CACHE_DIR=/work/cache python tools/train_vocabulary.py --kind lbd --k 10 --levels 3 \
        --out data/vocabulary/lbd_k10_L3.txt.gz

Default images: the bundled EuRoC and KITTI snippets (every frame, left camera) and the
left camera of the generated presets day-loop, dusk-loop, haze-row and dark-rows (seed 0,
full length, every ``--synthetic-stride``-th frame; generated into the cache if absent).
``--images FOLDER[:STRIDE]`` / ``--synthetic PRESET[:STRIDE]`` replace those lists.
A JSON record of what was trained on (``--record``) feeds the PROVENANCE note.
"""
from __future__ import annotations

import os
import sys

# Run as a script, Python puts tools/ first on sys.path; the repository root is what
# must be importable (canopy, shared), so it takes that place.
sys.path[0] = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

import argparse  # noqa: E402
import json  # noqa: E402
from pathlib import Path  # noqa: E402

from canopy.config import REPO_ROOT  # noqa: E402
from canopy.place.training import DESCRIPTOR_KINDS, ImageSource, train_from_images  # noqa: E402
from shared.errors import CanopyError  # noqa: E402

DEFAULT_IMAGES = ("data/euroc_v101_micro/mav0/cam0/data", "data/kitti06_snippet/image_l")
DEFAULT_PRESETS = ("day-loop", "dusk-loop", "haze-row", "dark-rows")


def synthetic_source(spec: str, default_stride: int) -> ImageSource:
    """``PRESET[:STRIDE]`` -> the left-camera folder of the cached (or newly generated) sequence."""
    from canopy.app import prepare_synthetic

    preset, _, stride = spec.partition(":")
    folder = Path(prepare_synthetic(preset, None, 0, progress=True)) / "mav0" / "cam0" / "data"
    return ImageSource(folder, int(stride) if stride else default_stride)


def default_sources(synthetic_stride: int) -> list[ImageSource]:
    return [ImageSource(REPO_ROOT / p) for p in DEFAULT_IMAGES] + \
        [synthetic_source(p, synthetic_stride) for p in DEFAULT_PRESETS]


def _parse(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kind", default="orb", choices=DESCRIPTOR_KINDS)
    ap.add_argument("--k", type=int, default=10, help="branching factor")
    ap.add_argument("--levels", type=int, default=4, help="tree depth L")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-iterations", type=int, default=10, help="k-majority rounds per node")
    ap.add_argument("--max-per-image", type=int, default=None, help="random subset of descriptors per image")
    ap.add_argument("--images", action="append", default=None, metavar="FOLDER[:STRIDE]")
    ap.add_argument("--synthetic", action="append", default=None, metavar="PRESET[:STRIDE]")
    ap.add_argument("--synthetic-stride", type=int, default=10, help="frame stride in generated sequences")
    ap.add_argument("--out", required=True, type=Path, help="vocabulary file (.txt or .txt.gz)")
    ap.add_argument("--record", type=Path, default=None, help="write the training record (JSON) here")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    a = _parse(argv)
    try:
        if a.images is None and a.synthetic is None:
            sources = default_sources(a.synthetic_stride)
        else:
            sources = [ImageSource.parse(s) for s in a.images or []] + \
                [synthetic_source(s, a.synthetic_stride) for s in a.synthetic or []]
        vocab, record = train_from_images(sources, a.kind, a.k, a.levels, a.seed, a.max_per_image,
                                          a.max_iterations)
        vocab.save(a.out)
    except CanopyError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    record["file"] = str(a.out)
    record["bytes"] = a.out.stat().st_size
    cache = os.environ.get("CANOPY_CACHE_DIR")
    for s in record["sources"]:  # portable names: repository-relative, cache as $CANOPY_CACHE_DIR
        if s["folder"].startswith(str(REPO_ROOT) + os.sep):
            s["folder"] = os.path.relpath(s["folder"], REPO_ROOT)
        elif cache and s["folder"].startswith(cache):
            s["folder"] = "$CANOPY_CACHE_DIR" + s["folder"][len(cache):]
    text = json.dumps(record, indent=1)
    print(vocab)
    print(text)
    if a.record is not None:
        a.record.parent.mkdir(parents=True, exist_ok=True)
        a.record.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
