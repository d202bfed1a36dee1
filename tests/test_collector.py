"""The output side of a run: incremental files, no fabricated poses, honest counts (issue 11)."""
import numpy as np

from actors.collector import RunCollector, format_summary
from protocol.messages import ActorStats, FramePose


def _pose(i, status="ok", reason=""):
    T = np.eye(4)
    T[0, 3] = 0.1 * i
    return FramePose(index=i, timestamp=10.0 + 0.1 * i, T_world_cam=T, status=status, n_inliers=50,
                     n_matches=60, is_keyframe=i == 0, ref_keyframe=-1, T_ref_cam=np.eye(4),
                     lost_reason=reason)


def _collect(tmp_path, statuses, n_frames, missing=()):
    stamps = 10.0 + 0.1 * np.arange(n_frames)
    col = RunCollector(n_frames=n_frames, progress=False, out_dir=tmp_path, frame_stamps=stamps)
    for i, st in enumerate(statuses):
        if i not in missing:
            col(_pose(i, st, "too few inliers" if st == "lost" else ""))
    return col


def test_files_grow_while_the_run_goes(tmp_path):
    col = _collect(tmp_path, ["init", "ok", "lost", "ok"], n_frames=10)
    # Before the end: what arrived is already on disk, lost frame without a pose.
    traj = np.loadtxt(tmp_path / "trajectory.tum")
    assert traj.shape == (3, 8) and np.allclose(traj[:, 0], [10.0, 10.1, 10.3])
    rows = (tmp_path / "frames.csv").read_text().splitlines()
    assert len(rows) == 5 and rows[3].split(",")[2:4] == ["lost", "too few inliers"]
    col(_pose(4))
    assert len(np.loadtxt(tmp_path / "trajectory.tum")) == 4


def test_final_outputs_hold_only_estimated_poses_and_say_why_others_have_none(tmp_path):
    # frames 0..7 of 10: frame 3 lost, frame 5 dropped (no event), 8 and 9 never reached
    col = _collect(tmp_path, ["init", "ok", "ok", "lost", "ok", "ok", "ok", "ok"], n_frames=10, missing={5})
    summary = col.write_outputs(tmp_path, None, {"ok": False})
    traj = np.loadtxt(tmp_path / "trajectory.tum")
    assert np.allclose(traj[:, 0], 10.0 + 0.1 * np.array([0, 1, 2, 4, 6, 7]))
    rows = [r.split(",") for r in (tmp_path / "frames.csv").read_text().splitlines()[1:]]
    assert [r[2] for r in rows] == ["init", "ok", "ok", "lost", "ok", "dropped", "ok", "ok",
                                    "not_reached", "not_reached"]
    assert all(r[3] for r in rows if r[2] in ("lost", "dropped", "not_reached"))
    assert float(rows[5][1]) == 10.5  # a dropped frame keeps its stamp
    t = summary["metrics"]["tracking"]
    assert (t["frames_total"], t["frames_tracked"], t["frames_lost"], t["frames_dropped"],
            t["frames_not_reached"]) == (10, 6, 1, 1, 2)
    assert t["tracking_success_percent"] == 60.0
    assert not list(tmp_path.glob("*.tmp"))  # replaced atomically, no temporary left


def test_realtime_summary_counts_dropped_frames_against_the_total(tmp_path):
    statuses = ["ok"] * 51
    col = _collect(tmp_path, statuses, n_frames=51, missing={5, 9, 13, 20, 33, 40, 47})
    col(ActorStats(actor="tracking", pid=1, seq=0, messages=44, dropped=7, service_ms=np.ones(3, np.float32),
                   queue_ms=np.ones(3, np.float32), cpu_percent=10.0, rss_mb=1.0, peak_rss_mb=1.0))
    summary = col.write_outputs(tmp_path, None, {"ok": True})
    t = summary["metrics"]["tracking"]
    assert t["frames_dropped"] == 7 and abs(t["tracking_success_percent"] - 100 * 44 / 51) < 1e-9
    text = format_summary(summary, "completed", 2)
    assert "86.3 %" in text and "7 dropped" in text


def test_top_view_of_kitti_is_x_z_and_of_euroc_x_y():
    """Camera y points down: KITTI's camera-frame ground truth is seen from above in x-z (it used
    to be plotted y-z, a side view); EuRoC's z-up world in x-y."""
    from canopy.report import top_view_axes
    from canopy.sources import open_source

    assert top_view_axes(open_source("kitti").ground_truth.poses) == (0, 2)
    assert top_view_axes(open_source("euroc").ground_truth.poses) == (0, 1)
