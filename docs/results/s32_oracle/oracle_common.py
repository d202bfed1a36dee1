"""s32: what the oracle scripts share: a cell run through the grid's in-process loop with section.field=value
settings, the clean pair's disparity at a degraded run's matches, and the mean step-length ratio."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from canopy.config import parse_value  # noqa: E402
from canopy.sources import BUNDLED_DATA  # noqa: E402


def parse_sets(items) -> dict:
    """["tracking.x=1", "mapping.y=2"] -> {"tracking": {"x": 1}, "mapping": {"y": 2}}."""
    sets: dict = {}
    for item in items:
        key, value = item.split("=", 1)
        section, field = key.split(".", 1)
        sets.setdefault(section, {})[field] = parse_value(value)
    return sets


def run_cell(path=None, settings=(), method="auto", config="kitti", kind="kitti", max_frames=None):
    """bench_enhance_diagnose.run on ``path`` (None: the bundled KITTI snippet; KITTI's ground truth for KITTI
    cells, the folder's own for generated ones) -> (result, rows). Looked up at call time, so a script's patch
    of that module (e.g. its open_source) applies."""
    import benchmarks.bench_enhance_diagnose as bd

    sets = parse_sets(settings)
    path = Path(path) if path else BUNDLED_DATA["kitti"]
    gt = BUNDLED_DATA["kitti"] if kind == "kitti" else path
    return bd.run(path, gt, config, {"method": method, **sets.get("enhancement", {})}, sets.get("tracking", {}),
                  max_frames, stereo=False, kind=kind, map_sets=sets.get("mapping", {}))


def clean_disparity(clean_frame, left, li, ur, params, scale_factors):
    """The clean pair's disparity at accepted matches (left keypoints ``li``, right columns ``ur`` after the
    rig's offset): centre SAD over +-2 px around ``ur`` on the clean pair, the same offset applied. Returns
    (disparity, measured)."""
    from canopy.frontend.stereo import subpixel_refine

    off = params.disparity_offset_for(left.extractor)
    uvl = left.uv[li].astype(np.float64)
    urc, _, ok = subpixel_refine(clean_frame.left, clean_frame.right, uvl, ur + off, left.octave[li], scale_factors,
                                 params.subpixel_window, 2, "centre", None)
    return uvl[:, 0] - (urc - off), ok


def step_ratio(rows) -> float:
    r = np.array([x.get("ratio", np.nan) for x in rows])
    return float(np.nanmean(r[1:]))
