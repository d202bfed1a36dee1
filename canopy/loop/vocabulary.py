"""Where loop closing gets its bag-of-words vocabulary (trained and loaded by
``canopy.place.vocabulary``; this module only picks the file)."""
from __future__ import annotations

from pathlib import Path

from shared.errors import ConfigError

REPO_ROOT = Path(__file__).resolve().parents[2]
VOCABULARY_DIR = REPO_ROOT / "data" / "vocabulary"


def default_vocabulary_path() -> Path:
    """The shipped ORB vocabulary: the DBoW2 file in data/vocabulary/ whose name starts with
    'orb' (the .json beside it describes how it was trained)."""
    found = sorted(p for p in VOCABULARY_DIR.glob("orb*") if p.is_file() and p.suffix != ".json")
    if not found:
        raise ConfigError(VOCABULARY_DIR, "no ORB vocabulary (orb*) shipped here; set loop.vocabulary in the config")
    return found[0]


def load_vocabulary(path: str | Path | None = None):
    from canopy.place.vocabulary import Vocabulary

    path = Path(path) if path else default_vocabulary_path()
    if not path.is_file():
        raise ConfigError(path, "vocabulary file not found (loop.vocabulary)")
    voc = Vocabulary.load(path)
    if not getattr(voc, "name", ""):
        try:
            voc.name = path.name
        except AttributeError:
            pass
    return voc


def check_vocabulary(path: str | Path | None = None) -> Path:
    """The vocabulary file loop closing will load, or a ConfigError saying what is missing."""
    path = Path(path) if path else default_vocabulary_path()
    if not path.is_file():
        raise ConfigError(path, "vocabulary file not found (loop.vocabulary)")
    try:
        import canopy.place.vocabulary  # noqa: F401
    except ImportError:
        raise ConfigError(path, "this build has no vocabulary loader (canopy.place.vocabulary); run with --no-loop") from None
    return path
