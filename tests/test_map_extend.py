"""Maps that outlive a run, extended: the first part of a generated day-loop is mapped and saved;
a later part (overlapping the first by 15 frames) is run with ``--load-map`` (no ``--localize``)
and ``--save-map``. Its first frame is found in the loaded map by database query, so the second
run's poses are in the first run's frame; it adds keyframes and landmarks to the loaded map and
the map it saves holds both, with ids that do not collide."""
from __future__ import annotations

import json

import numpy as np
import pytest

from canopy.loop.map_io import load_map, map_from_mapper, save_map
from canopy.loop.sequential import run_sequential_with_loops
from canopy.loop.vocabulary import load_vocabulary
from canopy.metrics import evaluate_trajectory
from canopy.sources import open_source
from canopy.trajectory_io import read_tum
from shared.errors import CanopyError

N_FRAMES = 80       # generated
N_MAPPED = 50       # first run: frames 0-49
SECOND_START = 35   # second run: frames 35-79 (15 frames over the mapped part, then 30 new ones)
ATE_BOUND_M = 0.01  # both runs (the mapping run's own ATE is ~3 mm)


@pytest.fixture(scope="module")
def extended(tmp_path_factory):
    from canopy.app import run_slam
    from canopy.synthetic import generate_sequence
    from tools.slice_sequence import slice_sequence

    root = tmp_path_factory.mktemp("extend")
    seq = generate_sequence("day-loop", root / "day", n_frames=N_FRAMES, seed=0, workers=1)
    src = open_source("euroc", str(seq))
    first = run_sequential_with_loops(src, load_vocabulary(), max_frames=N_MAPPED)
    first_ate = evaluate_trajectory(first.trajectory, src.ground_truth)["ate"]["rmse"]
    map_a = save_map(root / "a.canopy", map_from_mapper(first.mapper, "default"))
    later = slice_sequence(seq, root / "later", SECOND_START)
    out = root / "run2"
    result = run_slam("synthetic", path=str(later), out=str(out), progress=False, load_map=str(map_a),
                      save_map=str(root / "ab.canopy"))
    return {"first": first, "first_ate": first_ate, "map_a": map_a, "map_ab": root / "ab.canopy", "out": out,
            "result": result, "later": later, "root": root}


def test_extending_run_relocalises_and_adds_to_the_loaded_map(extended):
    out = extended["out"]
    assert extended["result"].outcome.ok, extended["result"].outcome.reason
    rows = [line.split(",") for line in (out / "frames.csv").read_text().splitlines()[1:]]
    status = np.array([r[2] for r in rows])
    assert len(rows) == N_FRAMES - SECOND_START
    assert status[0] == "ok"                        # found in the loaded map at once (database query)
    assert (status == "ok").all()                   # and tracked from then on, never a new map ("init")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tracking"]["keyframes"] >= 10   # the map is extended, not only tracked in
    assert extended["first_ate"] <= ATE_BOUND_M
    assert metrics["ate"]["rmse"] <= ATE_BOUND_M

    # same frame as the first run: on the frames both runs saw, the poses agree without any alignment
    t1 = extended["first"].trajectory
    t2 = read_tum(out / "trajectory.tum")
    common, i1, i2 = np.intersect1d(np.round(t1.stamps, 4), np.round(t2.stamps, 4), return_indices=True)
    assert len(common) == N_MAPPED - SECOND_START
    gap = np.linalg.norm(t1.poses[i1, :3, 3] - t2.poses[i2, :3, 3], axis=1)
    assert gap.max() < 0.01, gap


def test_saved_union_holds_loaded_and_new(extended):
    a, ab = load_map(extended["map_a"]), load_map(extended["map_ab"])
    assert len(np.unique(ab.kf_index)) == len(ab.kf_index)          # no colliding keyframe ids
    assert set(a.kf_index.tolist()) <= set(ab.kf_index.tolist())    # every loaded keyframe kept
    new = np.setdiff1d(ab.kf_index, a.kf_index)
    assert len(new) >= 10 and new.min() > a.kf_index.max()          # this run's keyframes after the loaded ones
    kept = np.isin(a.lm_id, ab.lm_id).mean()
    assert kept > 0.95                                              # loaded landmarks kept (a few culled by BA)
    assert len(ab.lm_id) > len(a.lm_id) + 1000                      # and new ones added
    # the new keyframes observe loaded landmarks: one map, not two side by side
    rows = np.concatenate([np.arange(*ab.keyframe_rows(k).indices(len(ab.uv)))
                           for k in np.flatnonzero(np.isin(ab.kf_index, new))])
    assert np.isin(ab.landmark[rows], a.lm_id).sum() > 100
    # covisibility links loaded and new keyframes
    cov = ab.covisibility
    assert (np.isin(cov[:, 0], a.kf_index) & np.isin(cov[:, 1], new)).any()


def test_extending_refuses_a_map_of_another_camera(extended, tmp_path):
    from canopy.app import run_slam

    with pytest.raises(CanopyError, match="another calibration"):
        run_slam("kitti", out=str(tmp_path / "k"), progress=False, load_map=str(extended["map_a"]))
