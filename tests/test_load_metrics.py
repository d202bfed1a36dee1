"""What the load test measures (benchmarks/bench_load.py, issue 12): end-to-end latency from the
frame read to the pose, the pose rate, and the saturation rule (< 1 % drops, latency not growing)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from actors.collector import RunCollector
from protocol.messages import FramePose

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_load", ROOT / "benchmarks" / "bench_load.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _pose(i: int, read_at: float, sent_at: float) -> FramePose:
    return FramePose(index=i, timestamp=0.1 * i, T_world_cam=np.eye(4), status="ok", n_inliers=1, n_matches=1,
                     is_keyframe=False, ref_keyframe=0, T_ref_cam=np.eye(4), sent_at=sent_at, frame_read_at=read_at)


def test_end_to_end_latency_and_pose_rate_from_the_pose_stream():
    col = RunCollector(n_frames=30, progress=False)
    # 30 frames read every 50 ms; latency grows 40 ms -> 330 ms (a queue building up)
    for i in range(30):
        col(_pose(i, 1000.0 + 0.05 * i, 1000.0 + 0.05 * i + 0.04 + 0.01 * i))
    col(_pose(30, 0.0, 0.0))  # a pose without timestamps (an older sender) is left out
    s = col.latency_summary()
    assert s["n"] == 30
    assert s["p50"] == pytest.approx(40 + 10 * 14.5, abs=0.5)
    assert s["max"] == pytest.approx(330, abs=0.5)
    assert s["first_third_p95"] < 140 < 240 < s["last_third_p95"]
    assert s["pose_rate_hz"] == pytest.approx(29 / (29 * 0.06), rel=1e-6)  # 60 ms between poses


def _row(rate: str, dropped: int, first_p95: float = 100.0, last_p95: float = 110.0, ok: bool = True) -> dict:
    return {"size": "euroc", "enhance": "none", "lines": False, "subscribers": 0, "rate": rate, "ok": ok,
            "frames_total": 200, "frames_dropped": dropped, "drop_fraction": dropped / 200,
            "poses_per_s": 42.0 if rate == "lockstep" else None,
            "end_to_end_ms": {"n": 200 - dropped, "first_third_p95": first_p95, "last_third_p95": last_p95},
            "actors": {"tracking": {"service_ms": {"p50": 30.0}}, "enhancement": {"service_ms": {"p50": 5.0}}}}


def test_saturation_is_the_highest_rate_with_few_drops_and_steady_latency(bench):
    rows = [_row("10", 0), _row("20", 1), _row("30", 1, last_p95=400.0), _row("40", 30), _row("lockstep", 0)]
    for r in rows:
        r["latency_bounded"] = bench.latency_bounded(r)
    assert [r["latency_bounded"] for r in rows] == [True, True, False, True, None]
    (sat,) = bench.saturation(rows)
    # 20 Hz: 0.5 % dropped, latency steady; 30 Hz: latency grows; 40 Hz: 15 % dropped
    assert sat["saturation_hz"] == 20.0 and sat["lockstep_poses_per_s"] == 42.0
    assert sat["first_to_saturate"] == "tracking"
    (none,) = bench.saturation([{**_row("10", 5), "latency_bounded": True}])
    assert none["saturation_hz"] is None and none["saturates_below_all_tried"]
