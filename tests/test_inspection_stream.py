"""Inspection stream and control (issue 12 part 3): map deltas instead of whole maps, JPEG frames
for clients that ask, loop events, and the map / pause / resume / save_map requests."""
from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest
import zmq

from actors.inspection import InspectionServer, inspection_request
from actors.inspection_stream import MOVE_TOLERANCE_M, InspectStream, MapDeltaTracker, apply_delta
from protocol.codec import decode, encode
from protocol.messages import FramePose, InspectFrame, LoopResult, MapDelta, MapSnapshot


def _snapshot(ids, points, final=False) -> MapSnapshot:
    return MapSnapshot(keyframe_indices=np.array([0, 5]), keyframe_stamps=np.array([1.0, 1.5]),
                       keyframe_poses=np.stack([np.eye(4)] * 2), points=np.asarray(points, np.float32),
                       point_ids=np.asarray(ids, np.int64), final=final)


def _pose(index: int, status: str = "ok") -> FramePose:
    return FramePose(index=index, timestamp=float(index), T_world_cam=np.eye(4), status=status, n_inliers=1,
                     n_matches=1, is_keyframe=False, ref_keyframe=0, T_ref_cam=np.eye(4))


def test_map_deltas_carry_only_new_moved_and_removed_points_and_rebuild_the_map():
    rng = np.random.default_rng(1)
    tracker, held = MapDeltaTracker(), {}
    pts = {i: rng.normal(size=3).astype(np.float32) for i in range(100)}
    d1 = tracker.delta(_snapshot(list(pts), list(pts.values())))
    assert len(d1.point_ids) == 100 and len(d1.removed_ids) == 0 and d1.seq == 1
    apply_delta(held, d1)
    # next snapshot: 0..49 culled, 100..149 new, 10 points moved by BA, 5 jittered below tolerance
    for i in range(50):
        del pts[i]
    pts.update({i: rng.normal(size=3).astype(np.float32) for i in range(100, 150)})
    for i in range(50, 60):
        pts[i] = pts[i] + np.float32(0.1)
    for i in range(60, 65):
        pts[i] = pts[i] + np.float32(MOVE_TOLERANCE_M / 10)
    order = rng.permutation(list(pts))  # the snapshot's order does not matter
    d2 = tracker.delta(_snapshot(order, [pts[i] for i in order], final=True))
    assert sorted(d2.point_ids.tolist()) == list(range(50, 60)) + list(range(100, 150))
    assert sorted(d2.removed_ids.tolist()) == list(range(50))
    assert d2.n_points == 100 and d2.final and d2.seq == 2
    apply_delta(held, d2)
    assert set(held) == set(pts)
    err = max(np.linalg.norm(held[i] - pts[i]) for i in pts)
    assert err <= MOVE_TOLERANCE_M
    # nothing changed: an empty delta
    d3 = tracker.delta(_snapshot(order, [pts[i] for i in order]))
    assert len(d3.point_ids) == 0 and len(d3.removed_ids) == 0 and d3.n_points == 100
    # a steady map costs the stream (and 20 subscribers) next to nothing; the whole map would not
    assert len(encode(d3)) < 0.25 * len(encode(_snapshot(order, [pts[i] for i in order])))


def test_frames_only_when_asked_for_and_rate_capped():
    image = np.full((480, 752), 90, np.uint8)
    now = [0.0]
    stream = InspectStream(frames=lambda i: image, frame_max_hz=5.0, clock=lambda: now[0])
    kinds = [k for k, _ in stream.events(_pose(0), encode(_pose(0)))]
    assert kinds == ["pose"]  # nobody asked for frames: no JPEG encoded
    stream.frames_wanted = True
    out = []
    for i in range(10):  # 10 poses in 1 s at 5 Hz max: 5 frames
        now[0] = 0.1 * i
        out += [(k, p) for k, p in stream.events(_pose(i), encode(_pose(i))) if k == "inspect_frame"]
    assert len(out) == 5
    frame = decode(out[0][1])
    assert isinstance(frame, InspectFrame) and (frame.width, frame.height) == (376, 240)
    img = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (240, 376) and abs(float(img.mean()) - 90) < 2
    lost = [k for k, _ in stream.events(_pose(20, "lost"), encode(_pose(20, "lost")))]
    assert lost == ["pose"]  # a lost frame's image is not sent


def test_server_sends_deltas_loops_and_frames_to_subscribers(tmp_path):
    zctx = zmq.Context()
    endpoint = f"ipc://{tmp_path}/insp"
    image = np.full((480, 752), 200, np.uint8)
    srv = InspectionServer(zctx, endpoint, frames=lambda i: image)
    sub = zctx.socket(zmq.SUB)
    for kind in ("map_delta", "map_snapshot", "loop_result", "inspect_frame"):
        sub.setsockopt(zmq.SUBSCRIBE, kind.encode())
    sub.connect(endpoint)
    try:
        deadline = time.monotonic() + 10
        while not srv.stream.frames_wanted and time.monotonic() < deadline:
            srv.serve(lambda c: ({}, None), "run")
            time.sleep(0.01)
        assert srv.stream.frames_wanted  # the subscription to inspect_frame switched JPEGs on
        snap = _snapshot([3, 4], [[0, 0, 1], [0, 1, 1]])
        loop = LoopResult(keyframe_index=9, closed=True, candidate=2, n_inliers=40, loops=1)
        got = []
        while len(got) < 3 and time.monotonic() < deadline:
            for msg in (snap, loop, _pose(7)):
                srv.publish_event(msg, encode(msg))
            while sub.poll(50):
                got.append(decode(sub.recv_multipart()[1]))
        kinds = {m.KIND for m in got}
        assert kinds == {"map_delta", "loop_result", "inspect_frame"}, kinds  # never a whole map_snapshot
        delta = next(m for m in got if isinstance(m, MapDelta))
        assert delta.point_ids.tolist() == [3, 4] and delta.n_points == 2
    finally:
        sub.close(0)
        srv.close()
        zctx.term()


class _Watcher(threading.Thread):
    """A remote client: subscribes to everything (and JPEG frames), pauses the run after the
    first pose, checks nothing moves, asks for the map, saves it, resumes."""

    def __init__(self, endpoint: str):
        super().__init__(daemon=True)
        self.endpoint = endpoint
        self.events: list = []
        self.results: dict = {}
        self.error: str | None = None

    def _request(self, command: str):
        reply = inspection_request(self.endpoint, command, timeout_s=10)
        assert reply is not None and reply.ok, f"{command}: {reply}"
        return reply.payload

    def run(self) -> None:
        ctx = zmq.Context.instance()
        sub = ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.SUBSCRIBE, b"")
        sub.setsockopt(zmq.SUBSCRIBE, b"inspect_frame")
        sub.connect(self.endpoint)
        poses = lambda: sum(isinstance(m, FramePose) for m in self.events)  # noqa: E731
        stage = "wait_pose"
        t_stage = time.monotonic()
        deadline = time.monotonic() + 240
        try:
            while time.monotonic() < deadline:
                if sub.poll(50):
                    msg = decode(sub.recv_multipart()[1])
                    self.events.append(msg)
                    if msg.KIND == "run_end":
                        return
                now = time.monotonic()
                if stage == "wait_pose" and poses() >= 3:
                    self.results["pause"] = self._request("pause")
                    stage, t_stage = "settle", now
                elif stage == "settle" and now - t_stage > 1.5:  # a frame in flight may still finish
                    self.results["poses_at_pause"] = poses()
                    stage, t_stage = "paused", now
                elif stage == "paused" and now - t_stage > 2.0:
                    self.results["poses_after_pause"] = poses()
                    self.results["status"] = self._request("status")
                    self.results["map"] = self._request("map")
                    self.results["save_map"] = self._request("save_map")
                    stage = "wait_saved"
                elif stage == "wait_saved" and any(m.KIND == "map_saved" for m in self.events):
                    self.results["resume"] = self._request("resume")
                    stage = "running"
        except AssertionError as exc:
            self.error = str(exc)
        finally:
            sub.close(0)


def test_remote_pause_map_save_resume_on_a_real_run(tmp_path):
    from canopy.app import run_slam
    from canopy.loop.map_io import load_map

    endpoint = f"ipc://{tmp_path}/inspect"
    watcher = _Watcher(endpoint)
    watcher.start()
    res = run_slam("euroc", max_frames=30, clock="lockstep", out=str(tmp_path / "run"), progress=False,
                   inspect=endpoint, loop=False)
    watcher.join(30)
    assert watcher.error is None, watcher.error
    assert res.outcome.ok, res.outcome.reason
    r = watcher.results
    assert {"pause", "status", "map", "save_map", "resume"} <= r.keys(), r.keys()
    # paused: no frame processed for 2 s, then the run went on to the end
    assert r["poses_after_pause"] == r["poses_at_pause"]
    assert r["status"]["paused"] is True
    assert res.summary["metrics"]["tracking"]["frames_processed"] == 30
    # the map request: the whole map as it was while paused
    assert len(r["map"]["points"]) == len(r["map"]["point_ids"]) > 50
    # save_map: written by local mapping, announced on the stream, loadable
    saved = next(m for m in watcher.events if m.KIND == "map_saved")
    assert saved.ok and saved.path == r["save_map"]["path"] and saved.points == len(r["map"]["points"])
    data = load_map(saved.path)
    assert len(data.lm_id) == saved.points and len(data.kf_index) == saved.keyframes > 0
    # map deltas, applied in order, give the final map; no whole map_snapshot was streamed
    kinds = {m.KIND for m in watcher.events}
    assert "map_snapshot" not in kinds and "map_delta" in kinds and "inspect_frame" in kinds
    held: dict = {}
    for d in (m for m in watcher.events if isinstance(m, MapDelta)):
        apply_delta(held, d)
    assert len(held) == res.summary["metrics"]["map_points"]
    frame = next(m for m in watcher.events if isinstance(m, InspectFrame))
    assert cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE).shape == (frame.height, frame.width)


def test_client_count_is_capped_and_a_freed_place_is_taken_again(tmp_path):
    """A client over the cap is refused by the ZAP handshake (ZMQ reports HANDSHAKE_FAILED_AUTH to
    it and does not retry by itself); once clients leave, new ones get in."""
    zctx = zmq.Context()
    endpoint = f"ipc://{tmp_path}/capped"
    srv = InspectionServer(zctx, endpoint, max_clients=3)
    subs: list[zmq.Socket] = []

    def connect() -> zmq.Socket:
        s = zctx.socket(zmq.SUB)
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.setsockopt(zmq.LINGER, 0)
        s.connect(endpoint)
        subs.append(s)
        return s

    def receiving(socks, seconds=3.0) -> list[bool]:
        """Which sockets get a message published while we wait (each drained)."""
        got = [False] * len(socks)
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not all(got):
            srv.serve(lambda c: ({}, None), "run")
            srv.publish("pose", encode(_pose(1)))
            for i, s in enumerate(socks):
                while s.poll(0):
                    s.recv_multipart()
                    got[i] = True
            time.sleep(0.02)
        return got

    try:
        first = []
        for _ in range(3):  # one at a time: each is in before the next knocks
            first.append(connect())
            assert receiving([first[-1]])[0]
        extra = [connect(), connect()]
        assert receiving(first + extra, 2.0) == [True, True, True, False, False]  # 4th and 5th refused
        for s in first[:2] + extra:  # two leave: two places for clients that knock again
            s.close(0)
            subs.remove(s)
        # a refused client knocks again, as a real one would (the server may not have seen the two
        # leave yet when the first knock comes)
        again = []
        for _ in range(2):
            for attempt in range(10):
                s = connect()
                if receiving([s], 1.0)[0]:
                    again.append(s)
                    break
                s.close(0)
                subs.remove(s)
        assert len(again) == 2 and receiving([first[2]] + again, 5.0) == [True, True, True]
        assert receiving([connect()], 1.0) == [False]  # full again
    finally:
        for s in subs:
            s.close(0)
        srv.close()
        zctx.term()


def test_control_requests_say_why_they_cannot_be_done(tmp_path):
    from actors.supervisor import MAX_SAVED_MAPS, Supervisor

    sup = Supervisor([], [], source="source", on_event=lambda m: None, save_map_dir=str(tmp_path))
    payload, error = sup._answer("pause")
    assert payload == {} and "'source' is not running" in error
    assert "'local_mapping' is not running" in sup._answer("save_map")[1]
    sup.maps_requested = MAX_SAVED_MAPS  # a client cannot fill the disk with maps
    assert f"at most {MAX_SAVED_MAPS}" in sup._answer("save_map")[1]
    no_dir = Supervisor([], [], source="source", on_event=lambda m: None)
    assert "not available" in no_dir._answer("save_map")[1]


def test_a_sigterm_during_a_published_event_is_not_swallowed(tmp_path):
    """The launcher's SIGTERM raises wherever the main thread is, also inside the preview
    fallback that keeps a failing delta or JPEG from ending the run. It must still end the run
    (CI once saw a SIGTERM there end with exit code 0), while an ordinary failure is absorbed."""
    from actors.supervisor import _Terminate

    zctx = zmq.Context()
    srv = InspectionServer(zctx, f"ipc://{tmp_path}/insp")
    try:
        def broken(msg, payload):
            raise ValueError("a delta that cannot be built")
        srv.stream.events = broken
        srv.publish_event(_pose(1), encode(_pose(1)))  # absorbed: the event goes out as is

        def terminated(msg, payload):
            raise _Terminate()
        srv.stream.events = terminated
        with pytest.raises(_Terminate):
            srv.publish_event(_pose(2), encode(_pose(2)))
    finally:
        srv.close()
        zctx.term()
