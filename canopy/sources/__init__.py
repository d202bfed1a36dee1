"""Stereo dataset sources: EuRoC ASL, KITTI odometry, plain image folders.

    src = open_source("euroc")            # bundled EuRoC V1_01 micro snippet
    src = open_source("kitti", "/data/kitti/sequences/06", max_frames=200)
    for frame in src: ...                 # rectified uint8 grey StereoFrame

Every source gives the calibration of the *rectified* pair, float-second
stamps and, where the dataset has it, ground truth as ``T_world_cam`` of the
rectified left camera. Bad input raises ``shared.errors.InputError`` naming
the file and the problem.
"""
from __future__ import annotations

from pathlib import Path

from shared.errors import InputError

from .base import StereoSource
from .euroc import EurocSource
from .folder import FolderSource
from .kitti import KittiSource

__all__ = ["open_source", "StereoSource", "EurocSource", "KittiSource", "FolderSource",
           "SOURCE_KINDS", "BUNDLED_DATA", "DATA_DIR"]

DATA_DIR = Path(__file__).resolve().parents[2] / "data"
BUNDLED_DATA = {"euroc": DATA_DIR / "euroc_v101_micro", "kitti": DATA_DIR / "kitti06_snippet"}
SOURCE_KINDS = {"euroc": EurocSource, "kitti": KittiSource, "folder": FolderSource}


def open_source(kind: str, path: str | Path | None = None, max_frames: int | None = None) -> StereoSource:
    """Open a stereo dataset.

    kind: "euroc", "kitti" or "folder". path: the dataset folder; None means
    the copy bundled in ``data/`` (euroc, kitti only). max_frames: keep at
    most the first N frames.
    """
    key = str(kind).strip().lower()
    if key not in SOURCE_KINDS:
        raise InputError(str(kind), f"unknown dataset kind; expected one of {', '.join(SOURCE_KINDS)}")
    if path is None:
        if key not in BUNDLED_DATA:
            raise InputError(f"<{key} path>", "a folder path is required for the 'folder' source")
        path = BUNDLED_DATA[key]
        if not Path(path).is_dir():
            raise InputError(path, "bundled dataset missing (expected it in the repository's data/ folder)")
    return SOURCE_KINDS[key](Path(path), max_frames=max_frames)
