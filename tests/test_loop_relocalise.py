"""Relocalisation by keyframe-database query (issue 10, part 3): KITTI 06 with 15 black
frames (longer than the motion-model bridge) after which the camera is back where it was
at frame 3 (a kidnapped camera): the frames after the gap are found in the same map by a
database query + stereo PnP; without the query tracking starts a new map there (ATE 13 m)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from canopy.loop.params import LoopParams
from canopy.loop.sequential import run_sequential_with_loops
from canopy.loop.vocabulary import load_vocabulary
from canopy.metrics import evaluate_trajectory
from canopy.sources import open_source
from shared.errors import InputError
from shared.types import Trajectory

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
from make_gap_sequence import make_gap_sequence, parse_range  # noqa: E402

GAP = "26-40"          # 15 frames: past the bridge (relocalise_bridge_frames = 10)


def test_kidnapped_camera_after_a_long_gap_is_found_in_the_same_map(tmp_path):
    src = open_source("kitti", make_gap_sequence(ROOT / "data" / "kitti06_snippet", tmp_path / "gap",
                                                 parse_range(GAP), resume_at=3))
    res = run_sequential_with_loops(src, load_vocabulary(), loop_params=LoopParams())
    st = np.array(res.statuses)
    assert (st[28:41] == "lost").all()      # the bridge (frames 28-38) ran out: no motion-model pose
    assert (st[41:] == "ok").all()          # frame 41 (= source frame 3) found by the query
    assert (st[1:] != "init").all()         # no new map segment
    tracked = np.isin(st, ["init", "ok"])
    ate = evaluate_trajectory(Trajectory(res.trajectory.stamps[tracked], res.trajectory.poses[tracked]),
                              src.ground_truth)["ate"]["rmse"]
    assert ate < 0.3
    assert len(res.closures) == 0           # a relocalisation, not a loop


def test_gap_tool_resume_at_names_bad_input(tmp_path):
    with pytest.raises(InputError, match="--resume-at"):
        make_gap_sequence(ROOT / "data" / "kitti06_snippet", tmp_path / "a", parse_range("20-24"), resume_at=30)
    with pytest.raises(InputError, match="--resume-at"):
        make_gap_sequence(ROOT / "data" / "kitti06_snippet", tmp_path / "b", [], resume_at=3)
