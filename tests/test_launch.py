"""End to end through launch.py: separate processes, outputs, failures.

These start real actor processes on the bundled data. The kill test watches
the run over the inspection endpoint (as a remote user would), SIGKILLs one
actor mid-run, and checks the promises: the run ends by itself with a
message naming the actor, the trajectory so far is on disk, and no
shared-memory segment is left behind.

Robust on a loaded machine (issue 11): kills wait for progress events, never
for wall-clock time; counts compare with what the events showed (realtime
drops frames when the machine is busy); time bounds are generous and say why.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from actors.supervisor import inspection_client
from protocol.messages import ActorReady, FramePose

ROOT = Path(__file__).resolve().parents[1]
# The supervisor gives actors grace_s (1 s) to stop, then kills them; on 2 cores shared with
# other jobs, writing the outputs and the interpreter's exit can add several seconds more. A run
# that does not end by itself hangs for minutes (heartbeat / lockstep waits), so 30 s separates
# the two without flaking; the shutdown latency itself is a benchmark figure, not a test.
RUN_ENDS_WITHIN_S = 30.0


def _shm_segments(launcher_pid: int) -> set[str]:
    """Ring segments of one launcher (named canopy_<launcher pid>_...): other runs on the same
    machine meanwhile are not this test's leaks."""
    return {n for n in os.listdir("/dev/shm") if n.startswith(f"canopy_{launcher_pid}_")}


def _launcher_pid(out: Path) -> int:
    return json.loads((out / "metrics.json").read_text())["run"]["launcher_pid"]


def _launch(*args, **kw):
    env = {**os.environ, **kw.get("env", {})}
    return subprocess.run([sys.executable, str(ROOT / "launch.py"), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=kw.get("timeout", 300), env=env)


def test_euroc_default_run_writes_every_output(tmp_path):
    out = tmp_path / "run"
    res = _launch("--dataset", "euroc", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "run summary" in res.stdout and "tracking success" in res.stdout
    for name in ("trajectory.tum", "keyframes.tum", "map_points.ply", "metrics.json", "stats.json", "frames.csv",
                 "trajectory.png", "config_used.yaml"):
        assert (out / name).is_file(), name
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tracking"]["frames_processed"] == 95
    stats = json.loads((out / "stats.json").read_text())
    assert {"source", "enhancement", "tracking", "local_mapping"} <= set(stats)
    assert stats["tracking"]["messages"] >= 95 and stats["tracking"]["service_ms"]["p50"] > 0
    assert stats["tracking"]["peak_rss_mb"] > 10
    # every frame-handling actor reports its own thread's CPU per frame (the 2-core budget of issue 8)
    for actor in ("source", "enhancement", "tracking", "local_mapping", "loop_closing"):
        assert stats[actor]["extra"]["threads"][actor]["cpu_ms_per_frame"] > 0, actor
    # keyframes carry sent_at, so local mapping's queue wait is measured for each of them
    assert stats["local_mapping"]["queue_ms"]["p50"] is not None
    traj = np.loadtxt(out / "trajectory.tum")
    assert traj.shape == (95, 8)
    em = metrics["est_motion"]  # the MAV sits still: ~zero motion is the drift test
    assert em["translation_m"] < 0.01 and em["rotation_deg"] < 0.5
    frames = (out / "frames.csv").read_text().splitlines()
    assert len(frames) == 96 and frames[0].startswith("index,timestamp,status")
    assert all(",none," in row for row in frames[1:])  # the enhancement decision of each frame
    assert not _shm_segments(_launcher_pid(out))


@pytest.mark.parametrize("victim", ["tracking", "local_mapping", "enhancement", "source"])
def test_sigkill_of_an_actor_ends_run_cleanly(tmp_path, victim):
    endpoint = f"ipc://{tmp_path}/inspect"
    out = tmp_path / "run"
    # half the dataset rate: the 95 frames then take ~9.5 s, so the signal sent once frame 15 is
    # posed always lands mid-run (at full rate a late subscriber could see frame 15 near the end,
    # and a run that finished first returns 0)
    config = tmp_path / "euroc_half_rate.yaml"
    config.write_text((ROOT / "configs" / "euroc.yaml").read_text().replace(
        "  clock: lockstep\n", "  clock: realtime\n  realtime_speed: 0.5\n", 1))
    assert "realtime_speed: 0.5" in config.read_text()
    proc = subprocess.Popen([sys.executable, str(ROOT / "launch.py"), "--dataset", "euroc", "--clock", "realtime",
                             "--config", str(config), "--out", str(out), "--inspect", endpoint, "--quiet"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pids, killed_at, posed = {}, None, 0
        for msg in inspection_client(endpoint, ["ready", "pose"], timeout_s=120):
            if isinstance(msg, ActorReady):
                pids[msg.actor] = msg.pid
            elif isinstance(msg, FramePose):
                posed += msg.status in ("init", "ok")
                if msg.index >= 20:
                    os.kill(pids[victim], signal.SIGKILL)
                    killed_at = time.monotonic()
                    break
        assert killed_at is not None, "the run never reached frame 20"
        stdout, stderr = proc.communicate(timeout=4 * RUN_ENDS_WITHIN_S)
        ended_after = time.monotonic() - killed_at
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1
    assert ended_after < RUN_ENDS_WITHIN_S, f"run took {ended_after:.1f} s to end"
    assert f"actor '{victim}' died (killed by SIGKILL)" in stderr
    assert "Traceback" not in stderr
    traj = np.loadtxt(out / "trajectory.tum")
    assert len(traj) >= posed  # every pose the run announced before the kill is on disk
    assert (out / "metrics.json").is_file()
    assert not _shm_segments(proc.pid), "shared memory leaked"


@pytest.mark.parametrize("args, fragment", [
    (["--dataset", "euroc", "--path", "/nonexistent/euroc"], "/nonexistent/euroc"),
    (["--dataset", "kitti", "--config", "/nonexistent/cfg.yaml"], "cfg.yaml: config file not found"),
    (["--dataset", "folder"], "folder"),
])
def test_bad_input_is_one_clear_line(args, fragment):
    res = _launch(*args, timeout=60)
    assert res.returncode == 2
    assert fragment in res.stderr
    assert "Traceback" not in res.stderr


def test_unknown_config_key_names_file_and_key(tmp_path):
    cfg = tmp_path / "bad.yaml"
    cfg.write_text("tracking:\n  n_featurez: 10\n")
    res = _launch("--dataset", "euroc", "--config", str(cfg), timeout=60)
    assert res.returncode == 2
    assert "bad.yaml" in res.stderr and "n_featurez" in res.stderr
    assert "Traceback" not in res.stderr


def test_corrupt_image_mid_run_names_the_file(tmp_path):
    import shutil
    data = tmp_path / "euroc"
    shutil.copytree(ROOT / "data" / "euroc_v101_micro", data, ignore=shutil.ignore_patterns("imu0"))
    victim = sorted((data / "mav0" / "cam0" / "data").glob("*.png"))[10]
    victim.write_bytes(b"\x89PNG\r\n\x1a\n not really a png")
    res = _launch("--dataset", "euroc", "--path", str(data), "--out", str(tmp_path / "run"), "--quiet", timeout=200)
    assert res.returncode == 1
    assert victim.name in res.stderr
    assert "Traceback" not in res.stderr
    assert len(np.loadtxt(tmp_path / "run" / "trajectory.tum")) == 10
    assert not _shm_segments(_launcher_pid(tmp_path / "run"))


def test_lockstep_runs_are_identical_across_processes(tmp_path):
    """lockstep promises the same trajectory on every run (seeded RANSAC, ordered messages)."""
    trajs = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        res = _launch("--dataset", "kitti", "--max-frames", "20", "--out", str(out), "--quiet")
        assert res.returncode == 0, res.stderr[-2000:]
        trajs.append((out / "trajectory.tum").read_text())
    a, b = ([ln for ln in t.splitlines() if not ln.startswith("#")] for t in trajs)
    assert len(a) == len(b) == 20
    diff = [(i, x, y) for i, (x, y) in enumerate(zip(a, b)) if x != y]
    assert not diff, f"{len(diff)} poses differ, first: {diff[0]}"
    # ... and it is the in-process reference's trajectory, with the same pipelining: tracking
    # overlaps local BA yet applies each map update before the same frame (MapUpdateSchedule)
    from canopy.config import load_run_config
    from canopy.pipeline import run_sequential
    from canopy.sources import open_source
    from canopy.trajectory_io import read_tum

    cfg = load_run_config("kitti")
    assert cfg.runtime.map_update_lag_frames >= 1  # the default pipelines
    ref = run_sequential(open_source("kitti", max_frames=20), cfg.tracking, cfg.mapping,
                         map_update_lag=cfg.runtime.map_update_lag_frames)
    got = read_tum(tmp_path / "run0" / "trajectory.tum").poses
    assert np.abs(got[:, :3, 3] - ref.trajectory.poses[:, :3, 3]).max() < 1e-6


def test_kitti_run_is_accurate_through_the_actors(tmp_path):
    out = tmp_path / "run"
    res = _launch("--dataset", "kitti", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["tracking"]["frames_processed"] == 51
    assert metrics["tracking"]["frames_lost"] == 0
    assert metrics["ate"]["rmse"] < 0.5
    assert metrics["kitti"]["t_rel_percent"] is not None


def test_synthetic_preset_generates_and_tracks(tmp_path):
    out = tmp_path / "run"
    res = _launch("--dataset", "synthetic", "--preset", "day-loop", "--max-frames", "60", "--out", str(out),
                  "--quiet", timeout=400, env={"CANOPY_CACHE_DIR": str(tmp_path / "cache")})
    assert res.returncode == 0, res.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["preset"] == "day-loop"
    assert metrics["tracking"]["frames_processed"] == 60 and metrics["tracking"]["frames_lost"] == 0
    assert metrics["ate"]["rmse"] < 0.05  # exact ground truth, 3 s of driving
    assert (tmp_path / "cache" / "synthetic").is_dir()


@pytest.mark.parametrize("args, fragment", [
    (["--dataset", "synthetic", "--preset", "moon-base"], "unknown preset 'moon-base'"),
    (["--dataset", "euroc", "--preset", "day-loop"], "--preset only applies"),
])
def test_bad_synthetic_arguments(args, fragment):
    res = _launch(*args, timeout=60)
    assert res.returncode == 2
    assert fragment in res.stderr and "Traceback" not in res.stderr


def test_lines_flow_through_the_actors(tmp_path):
    out = tmp_path / "run"
    res = _launch("--dataset", "euroc", "--lines", "--max-frames", "30", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr[-2000:]
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["run"]["lines"] is True and metrics["map_lines"] > 20
    header = (out / "map_lines.ply").read_bytes().split(b"end_header")[0].decode()
    assert f"element edge {metrics['map_lines']}" in header
    rows = (out / "frames.csv").read_text().splitlines()
    assert ",lines,line_inliers" in rows[0]  # (loop_candidate follows, issue 10)
    col = rows[0].split(",").index("lines")
    assert all(int(r.split(",")[col]) > 0 for r in rows[2:])  # per-frame line counts after the first frame
    em = metrics["est_motion"]  # static MAV: lines must not add drift
    assert em["translation_m"] < 0.01 and em["rotation_deg"] < 0.5


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.parametrize("how", ["ctrl-c", "sigterm", "ctrl-c-inherited-ignored"])
def test_user_interrupt_stops_cleanly_and_keeps_results(tmp_path, how):
    """Ctrl-C reaches the whole process group; SIGTERM only the launcher. Both end the run
    cleanly with what was computed written out and the shared memory removed. Ctrl-C works
    even when the launcher's parent ignored SIGINT (inherited across exec, and Python then
    leaves it ignored: the full suite once handed it down that way)."""
    endpoint = f"ipc://{tmp_path}/inspect"
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, str(ROOT / "launch.py"), "--dataset", "euroc", "--clock", "realtime",
                             "--out", str(out), "--inspect", endpoint, "--quiet"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True,
                            preexec_fn=_ignore_sigint if how == "ctrl-c-inherited-ignored" else None)
    try:
        posed = 0
        for msg in inspection_client(endpoint, ["pose"], timeout_s=120):
            posed += msg.status in ("init", "ok")
            if msg.index >= 15:
                break
        if how.startswith("ctrl-c"):
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=4 * RUN_ENDS_WITHIN_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 1
    assert "interrupted by the user" in stderr and "Traceback" not in stderr
    assert len(np.loadtxt(out / "trajectory.tum")) >= posed
    assert not _shm_segments(proc.pid)


def test_enhancement_actor_rejects_a_frame_of_the_wrong_size():
    from actors.enhancement import check_pair
    from shared.errors import InputError

    ok = np.zeros((480, 752), np.uint8)
    check_pair(ok, ok, 480, 752, 3)
    with pytest.raises(InputError, match=r"frame 7 \(right\).*float32"):
        check_pair(ok, ok.astype(np.float32), 480, 752, 7)
    with pytest.raises(InputError, match=r"frame 8 \(left\).*\(240, 376\)"):
        check_pair(ok[::2, ::2], ok, 480, 752, 8)


def test_record_writes_an_mcap_foxglove_reads(tmp_path):
    from collections import Counter

    from mcap.reader import make_reader

    out = tmp_path / "run"
    res = _launch("--dataset", "euroc", "--lines", "--record", "--max-frames", "25", "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr[-2000:]
    with open(out / "run.mcap", "rb") as f:
        reader = make_reader(f)  # a finished file: summary section present
        schemas = {s.name for s in reader.get_summary().schemas.values()}
        counts = Counter(ch.topic for _, ch, _ in reader.iter_messages())
    assert {"foxglove.PoseInFrame", "foxglove.CompressedImage", "foxglove.PointCloud",
            "foxglove.SceneUpdate", "foxglove.FrameTransform"} <= schemas
    assert counts["/camera/pose"] == 25 and counts["/camera/left/image"] == 25
    assert counts["/map/points"] >= 1 and counts["/map/lines"] >= 1
    assert "run.mcap" in res.stdout


def test_a_signal_held_while_outputs_are_written_is_reported_after(tmp_path):
    """SIGTERM and Ctrl-C that land while the results are written are noted, not acted on: the
    block finishes (the outputs complete), the handlers come back, and the caller sees them."""
    from actors.supervisor import hold_signals

    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    written = tmp_path / "trajectory.tum"
    with hold_signals(signal.SIGTERM, signal.SIGINT) as held:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handlers run between bytecodes: long before this returns
        written.write_text("0 0 0 0 0 0 0 1\n")
    assert written.read_text() and held.received == [signal.SIGTERM, signal.SIGINT]
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before
