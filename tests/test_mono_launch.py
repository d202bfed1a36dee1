"""``--sensor mono`` through launch.py: real actor processes, the left image only (issue 13)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _launch(*args, timeout=300):
    return subprocess.run([sys.executable, str(ROOT / "launch.py"), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout, env=dict(os.environ))


def test_kitti_mono_run_initialises_and_reports_sim3(tmp_path):
    out = tmp_path / "run"
    res = _launch("--dataset", "kitti", "--sensor", "mono", "--max-frames", "15", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr[-3000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["sensor"] == "mono"
    assert metrics["tracking"]["frames_processed"] == 15 and metrics["tracking"]["frames_lost"] == 0
    assert metrics["tracking"]["keyframes"] >= 3            # two at initialisation, more while driving
    sim3 = metrics["ate_sim3"]
    # the map unit is the initial median depth (metres per unit ~25 on KITTI); the frames before
    # initialisation sit at the start pose, so the error bound is loose here
    assert sim3["scale"] > 5.0 and sim3["rmse"] < 1.0
    assert (out / "keyframes.tum").is_file() and (out / "map_points.ply").is_file()
    # the loop closer runs in mono too (Sim(3), canopy.loop.mono): it saw every keyframe, closed no loop
    stats = json.loads((out / "stats.json").read_text())
    n_map_keyframes = sum(1 for ln in (out / "keyframes.tum").read_text().splitlines() if ln and not ln.startswith("#"))
    # (the map's keyframes: the initialisation's reference frame is one, though its frame is 'not_initialised')
    assert stats["loop_closing"]["extra"]["keyframes"] == n_map_keyframes
    assert metrics["loops"]["closed"] == 0


def test_unknown_sensor_in_config_is_a_clear_error(tmp_path):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("runtime:\n  sensor: sonar\n")
    res = _launch("--dataset", "kitti", "--config", str(cfg), "--max-frames", "2", "--quiet", timeout=120)
    assert res.returncode == 2
    assert "runtime.sensor" in res.stderr and "sonar" in res.stderr


def test_lines_with_mono_is_refused_before_any_process_starts():
    res = _launch("--dataset", "kitti", "--sensor", "mono", "--lines", "--max-frames", "2", "--quiet", timeout=120)
    assert res.returncode == 2
    assert "--lines" in res.stderr and "monocular" in res.stderr
