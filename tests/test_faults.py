"""Fault injection (issue 11): a killed launcher, a frozen actor, a killed recorder, and corrupt
images mid-run each end cleanly, name the cause, and leave parseable outputs behind.

Every kill waits for progress events from the run's inspection endpoint (never for wall-clock
time), and every time bound is generous: these tests run beside other jobs on 2 shared cores,
and what they check is that a run ends by itself with the right message, not how fast.
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from actors.supervisor import OWNER_FILE, RUN_DIR_PREFIX, inspection_client, sweep_stale_runs
from protocol.messages import ActorReady, FramePose

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT / "data" / "kitti06_snippet"
# A loaded 2-core machine can take seconds to start Python processes and write outputs; a run
# that hangs takes minutes. This bound tells the two apart without flaking.
END_WITHIN_S = 60


def _shm_segments(launcher_pid: int) -> set[str]:
    """Ring segments of one launcher (named canopy_<launcher pid>_...): other runs on the same
    machine meanwhile are not this test's leaks."""
    return {n for n in os.listdir("/dev/shm") if n.startswith(f"canopy_{launcher_pid}_")}


def _launcher_pid(out: Path) -> int:
    return json.loads((out / "metrics.json").read_text())["run"]["launcher_pid"]


def _start(tmp_path, *args, env=None):
    endpoint = f"ipc://{tmp_path}/inspect"
    proc = subprocess.Popen([sys.executable, str(ROOT / "launch.py"), "--out", str(tmp_path / "run"),
                             "--inspect", endpoint, "--quiet", *args],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    return proc, endpoint


def _watch_until(endpoint, n_posed):
    """Follow the run until ``n_posed`` frames have a pose; returns the actor pids."""
    pids, posed = {}, 0
    for msg in inspection_client(endpoint, ["ready", "pose"], timeout_s=180):
        if isinstance(msg, ActorReady):
            pids[msg.actor] = msg.pid
        elif isinstance(msg, FramePose):
            posed += msg.status in ("init", "ok")
            if posed >= n_posed:
                return pids
    raise AssertionError(f"the run never reached {n_posed} posed frames")


def _wait_for_size(path, n_bytes, timeout_s):
    """Wait until ``path`` holds more than ``n_bytes`` (a writer's first flush reached the disk)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size > n_bytes:
            return
        time.sleep(0.1)
    raise AssertionError(f"{path} never grew past {n_bytes} bytes in {timeout_s} s")


def _wait_gone(pids, timeout_s=END_WITHIN_S):
    deadline = time.monotonic() + timeout_s
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [p for p in alive if psutil.pid_exists(p) and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]
        time.sleep(0.2)
    return alive


def test_sigkill_of_the_launcher_leaves_a_parseable_trajectory_and_nothing_behind(tmp_path):
    # A private temp folder (short: ipc:// paths must fit a sockaddr_un): any other launcher on
    # the machine sweeps the shared one at its start-up and would remove the folder checked here.
    run_tmp = tempfile.mkdtemp(prefix="cf", dir="/tmp")
    proc, endpoint = _start(tmp_path, "--dataset", "euroc", env={**os.environ, "TMPDIR": run_tmp})
    try:
        pids = _watch_until(endpoint, 20)
        proc.kill()
        proc.wait(timeout=30)
        # Actors notice that their parent is gone and exit on their own.
        assert not _wait_gone(pids.values()), "actor processes outlived the launcher"
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate()
    traj = np.loadtxt(tmp_path / "run" / "trajectory.tum")  # appended and flushed as frames completed
    assert traj.ndim == 2 and traj.shape[1] == 8 and len(traj) >= 19  # the 20th may be in flight
    rows = (tmp_path / "run" / "frames.csv").read_text().splitlines()
    # the kill may land between a frame's trajectory line and its frames.csv row
    assert rows[0].startswith("index,timestamp,status,reason") and len(rows) - 1 >= len(traj) - 1
    # The dead launcher's socket folder is still there; the next run's start-up sweeps it.
    stale = [d for d in Path(run_tmp).glob(f"{RUN_DIR_PREFIX}*")
             if (d / OWNER_FILE).is_file() and (d / OWNER_FILE).read_text().split()[0] == str(proc.pid)]
    assert stale, "expected the killed launcher's socket folder"
    sweep_stale_runs(run_tmp)
    assert not any(d.exists() for d in stale)
    assert not _shm_segments(proc.pid), "shared memory leaked"
    shutil.rmtree(run_tmp, ignore_errors=True)


def test_frozen_local_mapping_is_blamed_not_tracking(tmp_path):
    cfg = tmp_path / "fast_heartbeat.yaml"
    cfg.write_text((ROOT / "configs" / "kitti.yaml").read_text().replace("heartbeat_timeout_s: 5.0",
                                                                         "heartbeat_timeout_s: 3.0"))
    assert "heartbeat_timeout_s: 3.0" in cfg.read_text()
    proc, endpoint = _start(tmp_path, "--dataset", "kitti", "--config", str(cfg))
    try:
        pids = _watch_until(endpoint, 5)
        os.kill(pids["local_mapping"], signal.SIGSTOP)  # lockstep: tracking soon waits on it
        _, stderr = proc.communicate(timeout=END_WITHIN_S + 60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1
    assert "actor 'local_mapping' is frozen" in stderr, stderr[-2000:]
    assert "Traceback" not in stderr
    assert not _wait_gone(pids.values())
    assert len(np.loadtxt(tmp_path / "run" / "trajectory.tum")) >= 5
    assert not _shm_segments(proc.pid)


def test_sigkill_of_the_recorder_leaves_an_mcap_that_opens(tmp_path):
    from mcap.reader import make_reader

    # lockstep: a busy machine makes realtime drop frames, and the kill waits for posed frames
    proc, endpoint = _start(tmp_path, "--dataset", "euroc", "--record")
    try:
        pids = _watch_until(endpoint, 10)
        # the recorder flushes a chunk at most once a second and may lag tracking on a loaded
        # machine: kill it once its first chunk is on disk (before that the file is the bare header)
        _wait_for_size(tmp_path / "run" / "run.mcap", 64, timeout_s=120)  # header alone: 45 B
        os.kill(pids["recorder"], signal.SIGKILL)
        _, stderr = proc.communicate(timeout=END_WITHIN_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1
    assert "actor 'recorder' died (killed by SIGKILL)" in stderr and "Traceback" not in stderr
    with open(tmp_path / "run" / "run.mcap", "rb") as f:
        reader = make_reader(f)  # seeking reader: needs the summary the launcher wrote on repair
        assert reader.get_summary() is not None
        n = sum(1 for _ in reader.iter_messages())
    assert n >= 1
    import json
    repaired = json.loads((tmp_path / "run" / "metrics.json").read_text())["run"]["recording_repaired_messages"]
    assert repaired == n  # the recorder's file had no summary: the launcher rebuilt it


@pytest.mark.parametrize("damage", ["truncated", "zero-byte"])
def test_damaged_image_mid_run_names_its_file_and_frame(tmp_path, damage):
    data = tmp_path / "kitti"
    for sub in ("image_l", "image_r"):
        (data / sub).mkdir(parents=True)
        for i in range(10):
            shutil.copy(KITTI / sub / f"{i:06d}.png", data / sub)
    for name in ("calib.txt", "times.txt", "poses.txt"):
        shutil.copy(KITTI / name, data)
    victim = data / "image_l" / "000006.png"
    blob = victim.read_bytes()
    victim.write_bytes(blob[: len(blob) // 3] if damage == "truncated" else b"")
    res = subprocess.run([sys.executable, str(ROOT / "launch.py"), "--dataset", "kitti", "--path", str(data),
                          "--out", str(tmp_path / "run"), "--quiet"], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 1
    assert "000006.png" in res.stderr and "at frame 6" in res.stderr, res.stderr[-2000:]
    assert "Traceback" not in res.stderr
    assert len(np.loadtxt(tmp_path / "run" / "trajectory.tum")) == 6
    rows = [r.split(",") for r in (tmp_path / "run" / "frames.csv").read_text().splitlines()[1:]]
    assert [r[2] for r in rows] == ["init"] + ["ok"] * 5 + ["not_reached"] * 4
    assert not _shm_segments(_launcher_pid(tmp_path / "run"))
