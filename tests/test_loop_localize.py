"""Maps that outlive a run: a day-loop map saved by one run, loaded by the next with
``--localize``: the first frame is found in it by database query + stereo PnP, every frame
is tracked in it without adding keyframes, and the trajectory is as good as the mapping run's."""
from __future__ import annotations

import json

import numpy as np
import pytest

from canopy.loop.map_io import load_map, map_from_mapper, save_map
from canopy.loop.sequential import run_sequential_with_loops
from canopy.loop.vocabulary import load_vocabulary
from canopy.metrics import evaluate_trajectory
from canopy.sources import open_source
from shared.errors import CanopyError

N_FRAMES = 60


@pytest.fixture(scope="module")
def day_loop_map(tmp_path_factory):
    from canopy.synthetic import generate_sequence

    root = tmp_path_factory.mktemp("localize")
    seq = generate_sequence("day-loop", root / "day", n_frames=N_FRAMES, seed=0, workers=1)
    src = open_source("euroc", str(seq))
    mapping = run_sequential_with_loops(src, load_vocabulary())
    ate = evaluate_trajectory(mapping.trajectory, src.ground_truth)["ate"]["rmse"]
    path = save_map(root / "day.canopy", map_from_mapper(mapping.mapper, "default"))
    return {"seq": str(seq), "map": path, "ate": ate, "n_keyframes": len(mapping.mapper.keyframes), "root": root}


def test_localise_in_a_saved_map(day_loop_map):
    from canopy.app import run_slam

    out = day_loop_map["root"] / "loc"
    result = run_slam("synthetic", path=day_loop_map["seq"], out=str(out), progress=False,
                      load_map=str(day_loop_map["map"]), localize=True)
    assert result.outcome.ok, result.outcome.reason
    rows = [line.split(",") for line in (out / "frames.csv").read_text().splitlines()[1:]]
    status = np.array([r[2] for r in rows])
    first = int(np.flatnonzero(status == "ok")[0])
    assert first <= 5                                    # found in the map within 5 frames of the start
    assert (status[first:] == "ok").all()                # and tracked in it from then on
    assert not np.isin(status, ["init"]).any()           # never a new map
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tracking"]["keyframes"] == 0         # localisation only: the map is not changed
    assert metrics["ate"]["rmse"] <= day_loop_map["ate"]  # as good as the run that made the map
    assert metrics["n_matched"] >= N_FRAMES - 5


def test_load_map_bad_input_is_one_line(day_loop_map, tmp_path):
    from canopy.app import run_slam

    with pytest.raises(CanopyError, match="--localize.*--load-map"):
        run_slam("synthetic", path=day_loop_map["seq"], out=str(tmp_path / "a"), progress=False, localize=True)
    with pytest.raises(CanopyError, match="map file not found"):
        run_slam("synthetic", path=day_loop_map["seq"], out=str(tmp_path / "b"), progress=False,
                 load_map=str(tmp_path / "missing.canopy"), localize=True)
    # a KITTI camera cannot use a map of the generated orchard's
    with pytest.raises(CanopyError, match="another calibration"):
        run_slam("kitti", out=str(tmp_path / "c"), progress=False, load_map=str(day_loop_map["map"]), localize=True)
    assert len(load_map(day_loop_map["map"]).kf_index) == day_loop_map["n_keyframes"]
