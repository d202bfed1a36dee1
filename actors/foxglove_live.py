"""Live view of a run in the Foxglove app, over Foxglove's WebSocket protocol (issue 12).

``--foxglove [HOST:PORT]`` (default ``127.0.0.1:8765``): the launcher serves its run with the
``foxglove-sdk`` package (optional extra ``.[foxglove]``), in Foxglove's well-known protobuf
schemas, on the same topics as the ``.mcap`` recording (``canopy.recording``):

============================  ===========================  ===========================================
topic                         schema                       content
============================  ===========================  ===========================================
``/camera/pose``              ``foxglove.PoseInFrame``     T_world_cam of every frame with a pose
``/tf``                       ``foxglove.FrameTransform``  ``world`` -> ``camera`` (same pose)
``/camera/left/image``        ``foxglove.CompressedImage`` enhanced left image, downscaled JPEG, <= 10 Hz
``/map/points``               ``foxglove.PointCloud``      the map's points (float32 x, y, z) per snapshot
``/map/lines``                ``foxglove.SceneUpdate``     the map's line segments (with --lines), one LINE_LIST
``/events``                   ``foxglove.Log``             run start / end, loops closed, actor errors
============================  ===========================  ===========================================

The Foxglove WebSocket protocol has no authentication, so only a loopback address is served;
to watch from another machine, forward the port (``ssh -L 8765:127.0.0.1:8765 robot``).
Work is done only for channels a client subscribed to (``has_sinks``): with no client connected
the bridge costs the launcher nothing but the check. Images are read from the enhanced frame ring
in shared memory (the frame a pose belongs to is still there: the ring holds several frames), so no
actor changes and no image crosses ZeroMQ.
"""
from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from actors.frame_preview import RingFrames, jpeg_preview
from canopy.recording import CAMERA_FRAME, IMAGE_TOPIC, LINES_TOPIC, POINTS_TOPIC, POSE_TOPIC, TF_TOPIC, WORLD_FRAME
from protocol.messages import ActorError, FramePose, LoopResult, MapSnapshot
from shared.errors import ConfigError
from shared.geometry import rot_to_quat_wxyz

DEFAULT_ADDRESS = "127.0.0.1:8765"
LINE_COLOR = (1.0, 0.55, 0.0, 1.0)   # as in the recording (canopy.recording.McapRecorder.add_lines)
LINE_THICKNESS_PX = 2.0
EVENTS_TOPIC = "/events"
IMAGE_MIN_PERIOD_S = 0.1        # at most 10 images/s, whatever the frame rate
MAX_MESSAGE_BACKLOG = 256       # per client; the SDK drops the oldest message of a slow client
POSED_STATUSES = ("init", "ok", "predicted")
CLIENT_LOGGER = "foxglove.websocket.connected_client"  # the SDK logs every bad client message here
MAX_CLIENT_LOG_RECORDS = 10     # then silence: a client sending garbage must not flood the launcher's log
INSTALL_HINT = "pip install 'canopy-slam[foxglove]' (or pip install foxglove-sdk)"


def parse_foxglove_address(text: str | None) -> tuple[str, int]:
    """``HOST:PORT`` (loopback only) -> (host, port); ConfigError naming the input otherwise."""
    import ipaddress
    import socket

    where = f"--foxglove {text}"
    host, sep, port = (text or "").rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ConfigError(where, "expected HOST:PORT, e.g. 127.0.0.1:8765")
    try:
        addrs = {info[4][0] for info in socket.getaddrinfo(host.strip("[]"), None)}
    except (socket.gaierror, UnicodeError):
        raise ConfigError(where, f"unknown host {host!r}") from None
    if not all(ipaddress.ip_address(a.split("%")[0]).is_loopback for a in addrs):
        raise ConfigError(where, "the Foxglove WebSocket protocol has no authentication: serve a loopback "
                                 "address and forward the port (ssh -L 8765:127.0.0.1:8765 HOST)")
    return host.strip("[]"), int(port)


def _sdk():
    try:
        import foxglove
    except ImportError:
        raise ConfigError("--foxglove", f"needs the foxglove-sdk package: {INSTALL_HINT}") from None
    return foxglove


def _stamp(t: float):
    from foxglove.messages import Timestamp

    t = max(0.0, float(t)) if np.isfinite(t) else 0.0
    sec = int(t)
    return Timestamp(sec=sec, nsec=min(999_999_999, int(round((t - sec) * 1e9))))


def _pose_parts(T: np.ndarray):
    from foxglove.messages import Quaternion, Vector3

    T = np.asarray(T, np.float64)
    q = rot_to_quat_wxyz(T[None, :3, :3])[0]
    return (Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])))


class _FirstRecordsOnly(logging.Filter):
    def __init__(self, limit: int):
        super().__init__()
        self.limit, self.seen = limit, 0

    def filter(self, record: logging.LogRecord) -> bool:
        self.seen += 1
        if self.seen == self.limit:
            record.msg = f"{record.getMessage()} (further client errors not logged)"
            record.args = ()
        return self.seen <= self.limit


class FoxgloveLive:
    """A Foxglove WebSocket server fed with run events: call it with every event (``bridge(msg)``)."""

    def __init__(self, host: str, port: int, frames=None, name: str = "canopy-slam", run_id: str = ""):
        foxglove = _sdk()
        from foxglove.channels import (CompressedImageChannel, FrameTransformChannel, LogChannel,
                                       PointCloudChannel, PoseInFrameChannel, SceneUpdateChannel)

        self.context = foxglove.Context()  # our own: never mixes with another server in this process
        client_log = logging.getLogger(CLIENT_LOGGER)
        if not any(isinstance(f, _FirstRecordsOnly) for f in client_log.filters):
            client_log.addFilter(_FirstRecordsOnly(MAX_CLIENT_LOG_RECORDS))
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context,
                                                message_backlog_size=MAX_MESSAGE_BACKLOG)
        except RuntimeError as exc:
            raise ConfigError(f"--foxglove {host}:{port}", f"cannot serve there: {exc}") from None
        self.frames = frames
        self.run_id = run_id
        self.pose_channel = PoseInFrameChannel(POSE_TOPIC, context=self.context)
        self.tf_channel = FrameTransformChannel(TF_TOPIC, context=self.context)
        self.image_channel = CompressedImageChannel(IMAGE_TOPIC, context=self.context)
        self.points_channel = PointCloudChannel(POINTS_TOPIC, context=self.context)
        self.lines_channel = SceneUpdateChannel(LINES_TOPIC, context=self.context)
        self.events_channel = LogChannel(EVENTS_TOPIC, context=self.context)
        self._last_image_t = -np.inf
        self.sent = {"poses": 0, "images": 0, "maps": 0, "lines": 0, "events": 0}
        self._event(f"run {run_id} started" if run_id else "run started")

    @property
    def port(self) -> int:
        return int(self.server.port)

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def __call__(self, msg: Any) -> None:
        try:
            if isinstance(msg, FramePose):
                self._pose(msg)
            elif isinstance(msg, MapSnapshot):
                self._map(msg)
            elif isinstance(msg, LoopResult) and msg.closed:
                self._event(f"loop closed: keyframe {msg.keyframe_index} <-> {msg.candidate} "
                            f"({msg.n_inliers} inliers, {msg.loops} so far)")
            elif isinstance(msg, ActorError):
                self._event(f"{msg.actor}: {msg.error}", error=True)
        except Exception as exc:  # a viewer must never cost the run: say so on /events and go on
            try:
                self._event(f"live view: {type(msg).__name__} not shown ({type(exc).__name__}: {exc})", error=True)
            except Exception:
                pass

    def _pose(self, p: FramePose) -> None:
        from foxglove.messages import FrameTransform, Pose, PoseInFrame

        if p.status not in POSED_STATUSES:
            return
        stamp = _stamp(p.timestamp)
        position, orientation = _pose_parts(p.T_world_cam)
        if self.pose_channel.has_sinks():
            self.pose_channel.log(PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME,
                                              pose=Pose(position=position, orientation=orientation)))
            self.sent["poses"] += 1
        if self.tf_channel.has_sinks():
            self.tf_channel.log(FrameTransform(timestamp=stamp, parent_frame_id=WORLD_FRAME,
                                               child_frame_id=CAMERA_FRAME, translation=position,
                                               rotation=orientation))
        now = time.monotonic()
        if self.frames is not None and self.image_channel.has_sinks() and now - self._last_image_t >= IMAGE_MIN_PERIOD_S:
            image = self.frames(p.index)
            if image is not None:
                self.log_image(p.timestamp, image)
                self._last_image_t = now

    def log_image(self, stamp_s: float, image: np.ndarray) -> None:
        from foxglove.messages import CompressedImage

        self.image_channel.log(CompressedImage(timestamp=_stamp(stamp_s), frame_id=CAMERA_FRAME,
                                               data=jpeg_preview(image), format="jpeg"))
        self.sent["images"] += 1

    def _map(self, snap: MapSnapshot) -> None:
        from foxglove.messages import PackedElementField, PackedElementFieldNumericType, PointCloud, Pose

        self._lines(snap)
        if not self.points_channel.has_sinks():
            return
        pts = np.ascontiguousarray(np.asarray(snap.points, np.float32).reshape(-1, 3), dtype="<f4")
        stamp = float(snap.keyframe_stamps[-1]) if len(snap.keyframe_stamps) else 0.0
        f32 = PackedElementFieldNumericType.Float32
        position, orientation = _pose_parts(np.eye(4))
        self.points_channel.log(PointCloud(
            timestamp=_stamp(stamp), frame_id=WORLD_FRAME, pose=Pose(position=position, orientation=orientation),
            point_stride=12, fields=[PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate("xyz")],
            data=pts.tobytes()))
        self.sent["maps"] += 1

    def _lines(self, snap: MapSnapshot) -> None:
        from foxglove.messages import (Color, LinePrimitive, LinePrimitiveLineType, Point3, Pose, SceneEntity,
                                       SceneUpdate)

        seg = np.asarray(snap.lines, np.float64).reshape(-1, 2, 3)
        seg = seg[np.isfinite(seg).all(axis=(1, 2))]
        if not len(seg) or not self.lines_channel.has_sinks():
            return
        stamp = _stamp(float(snap.keyframe_stamps[-1]) if len(snap.keyframe_stamps) else 0.0)
        position, orientation = _pose_parts(np.eye(4))
        r, g, b, a = LINE_COLOR
        line = LinePrimitive(type=LinePrimitiveLineType.LineList, pose=Pose(position=position, orientation=orientation),
                             thickness=LINE_THICKNESS_PX, scale_invariant=True,
                             points=[Point3(x=x, y=y, z=z) for x, y, z in seg.reshape(-1, 3).tolist()],
                             color=Color(r=r, g=g, b=b, a=a))
        # a fixed entity id: each update replaces the previous map's lines
        self.lines_channel.log(SceneUpdate(entities=[SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id="map_lines",
                                                                 lines=[line])]))
        self.sent["lines"] += 1

    def _event(self, text: str, error: bool = False) -> None:
        from foxglove.messages import Log, LogLevel

        if self.events_channel.has_sinks():
            self.events_channel.log(Log(timestamp=_stamp(time.time()), level=LogLevel.Error if error else LogLevel.Info,
                                        message=text, name="canopy-slam"))
            self.sent["events"] += 1

    def close(self, reason: str = "") -> None:
        if self.server is None:
            return
        self._event(f"run {self.run_id} ended: {reason}" if reason else "run ended")
        if self.frames is not None and hasattr(self.frames, "close"):
            self.frames.close()
        self.server.stop()
        self.server = None


def check_foxglove(address: str) -> tuple[str, int]:
    """Before anything starts: the SDK is installed and the address is a loopback HOST:PORT."""
    _sdk()
    return parse_foxglove_address(address)


def start_foxglove(address: str, ring_name: str | None = None, run_id: str = "") -> FoxgloveLive:
    """Validate ``--foxglove`` and start serving (before any actor starts: a busy port fails fast)."""
    host, port = parse_foxglove_address(address)
    return FoxgloveLive(host, port, frames=RingFrames(ring_name) if ring_name else None, run_id=run_id)
