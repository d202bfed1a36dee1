"""Loop closing in the SLAM loop: no false loop on the real snippets (KITTI 06, EuRoC V1_01),
and the actor system runs with the loop closer and reports its count."""
from __future__ import annotations

import json

import numpy as np
import pytest

from canopy.loop.sequential import run_sequential_with_loops
from canopy.loop.vocabulary import load_vocabulary
from canopy.metrics import evaluate_trajectory
from canopy.sources import open_source


@pytest.fixture(scope="module")
def vocabulary():
    return load_vocabulary()


@pytest.mark.parametrize("kind, frames", [("kitti", 51), ("euroc", 95)])
def test_no_false_loop_on_real_snippets(vocabulary, kind, frames):
    src = open_source(kind, max_frames=frames)
    res = run_sequential_with_loops(src, vocabulary, max_frames=frames)
    assert res.detection["keyframes"] > 5
    assert res.closures == []
    assert all(s != "lost" for s in res.statuses)


def test_actor_run_with_loop_closer_reports_loops(tmp_path):
    from canopy.app import run_slam

    result = run_slam("kitti", out=str(tmp_path / "run"), max_frames=25, progress=False, loop=True)
    assert result.outcome.ok, result.outcome.reason
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    stats = json.loads((tmp_path / "run" / "stats.json").read_text())
    assert metrics["loops"]["closed"] == 0
    assert stats["loop_closing"]["extra"]["keyframes"] == metrics["tracking"]["keyframes"]
    assert "loops closed         0" in result.text
    assert "loop_candidate" in (tmp_path / "run" / "frames.csv").read_text().splitlines()[0]
    assert metrics["ate"]["rmse"] < 0.5
