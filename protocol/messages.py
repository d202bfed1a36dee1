"""Every message that crosses a process boundary, defined once.

Frames never travel here on one host: a ``FrameHandle`` names a slot of a
shared-memory ring and the slot's generation, so a reader can tell that the
slot was overwritten under it (see ``shared.ring``). Only what the receiver
needs is sent (pySLAM's explicit cross-process messages), never a live map.
"""
from __future__ import annotations

import math
from dataclasses import field

import numpy as np

from protocol.codec import message


# --- lifecycle and supervision -------------------------------------------------

@message("ready")
class ActorReady:
    """An actor finished its set-up and is listening."""
    actor: str
    pid: int


@message("start")
class Start:
    """Supervisor → source: every actor is ready, begin streaming."""


@message("shutdown")
class Shutdown:
    """Supervisor → actor: stop now (reason is for the log)."""
    reason: str = ""


@message("end_of_stream")
class EndOfStream:
    """Flows down the pipeline after the last frame; each actor forwards it."""
    n_frames: int
    sent_at: float = 0.0


@message("actor_error")
class ActorError:
    """An actor failed; ``error`` is one line for the user, ``detail`` the traceback."""
    actor: str
    error: str
    detail: str = ""
    frame_index: int = -1


@message("stats")
class ActorStats:
    """Published by every actor once a second; doubles as its heartbeat."""
    actor: str
    pid: int
    seq: int
    messages: int
    dropped: int
    service_ms: np.ndarray  # recent per-message service times (ms)
    queue_ms: np.ndarray    # recent per-message queue waits (ms)
    cpu_percent: float
    rss_mb: float
    peak_rss_mb: float
    extra: dict = field(default_factory=dict)
    final: bool = False


# --- frames --------------------------------------------------------------------

@message("frame")
class FrameHandle:
    """A stereo frame sitting in shared-memory ring ``ring`` at ``slot``."""
    index: int
    timestamp: float
    ring: str
    slot: int
    generation: int
    sent_at: float
    info: dict = field(default_factory=dict)
    read_at: float = 0.0        # wall time the source began reading the frame: end-to-end latency starts here


@message("frame_done")
class FrameDone:
    """Tracking → source in lockstep: frame ``index`` is fully processed."""
    index: int
    sent_at: float = 0.0


# --- SLAM results ---------------------------------------------------------------

@message("pose")
class FramePose:
    """Tracking → supervisor: the pose of one frame, as tracked.

    ``ref_keyframe`` and ``T_ref_cam`` let the supervisor re-express the pose
    after local BA or a loop correction moved the reference keyframe
    (ORB-SLAM's relative-to-reference trajectory).
    """
    index: int
    timestamp: float
    T_world_cam: np.ndarray
    status: str               # "init" | "ok" | "predicted" (motion model bridging a gap) | "lost"
    n_inliers: int
    n_matches: int
    is_keyframe: bool
    ref_keyframe: int
    T_ref_cam: np.ndarray
    timings_ms: dict = field(default_factory=dict)
    sent_at: float = 0.0
    enhancement: dict = field(default_factory=dict)  # method used, image statistics before/after
    n_lines: int = 0            # left segments detected (0 without --lines)
    n_line_inliers: int = 0     # line matches kept by the pose refinement
    lost_reason: str = ""       # why a "predicted" / "lost" frame has no tracked pose ("" when tracked)
    frame_read_at: float = 0.0  # FrameHandle.read_at: end-to-end latency = sent_at - frame_read_at


@message("map_snapshot")
class MapSnapshot:
    """Local mapping → supervisor: keyframe poses and map points so far."""
    keyframe_indices: np.ndarray   # (K,) int64 frame indices
    keyframe_stamps: np.ndarray    # (K,)
    keyframe_poses: np.ndarray     # (K, 4, 4) T_world_cam
    points: np.ndarray             # (N, 3) float32
    final: bool = False
    timings_ms: dict = field(default_factory=dict)
    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3), np.float32))  # (L, 2, 3) endpoints
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))  # (N,) landmark id of each point


# --- tracking <-> local mapping --------------------------------------------------

@message("keyframe")
class KeyframeData:
    """A keyframe as tracking hands it to local mapping.

    Row i describes left keypoint i. ``landmark_ids[i]`` is the existing map landmark the
    keypoint was matched to (inlier of the pose estimate), -1 for none.
    ``new_landmark_ids[i]`` is the id tracking reserved for a landmark created from the
    keypoint's stereo depth (-1 for none): tracking is the only allocator of landmark ids,
    so it can track the new points before the map update comes back.
    ``seen_*`` count, per landmark, in how many frames since the previous keyframe it was
    predicted in view and how many times it was matched (ORB-SLAM's found ratio).
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray      # (4,4)
    uv: np.ndarray               # (N,2) float32
    u_right: np.ndarray          # (N,) float32, -1 where no stereo match
    depth: np.ndarray            # (N,) float32, -1 where no stereo match
    descriptors: np.ndarray      # (N,32) uint8
    octave: np.ndarray           # (N,) int32
    landmark_ids: np.ndarray     # (N,) int64
    new_landmark_ids: np.ndarray  # (N,) int64
    scale_factor: float = 1.2    # ORB pyramid scale: sigma of a measurement = scale**octave
    restart: bool = False        # first keyframe of a new map segment (start or after "lost")
    seen_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    seen_visible: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    seen_found: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    # line observations (issue 4; empty when tracking runs without lines). Row j is a left
    # segment matched to map line ``line_ids[j]`` or creating line ``new_line_ids[j]``.
    line_segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))        # (K,4) px
    line_segments_right: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))  # NaN: no stereo
    line_descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))      # (K,32) LBD
    line_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))                    # (K,) -1: none
    new_line_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))                # (K,) -1: none
    line_endpoints_cam: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))            # (K,2,3) NaN: none
    sent_at: float = 0.0         # wall time sent (filled in by ActorContext.send): local mapping's queue wait
    # loop corrections tracking had applied when it tracked this keyframe (issue 10): local
    # mapping brings a keyframe tracked before a correction reached tracking up to date
    loop_epoch: int = 0
    # the scene's up measured in this keyframe's camera frame (x right, y down, z forward; unit), NaN when
    # none (tracking.vertical_estimate off or too little vertical structure), and its angular 1-sigma (deg):
    # mapping.attitude_prior's measurement (canopy.backend.attitude_prior)
    up_cam: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    up_sigma_deg: float = math.nan

    def __len__(self) -> int:
        return len(self.uv)


@message("local_map_update")
class LocalMapUpdate:
    """What local mapping sends back after inserting keyframe ``keyframe_index``.

    The landmarks are the local map (points seen by the local window); ``keyframe_poses``
    holds the bundle-adjusted T_world_cam of the window keyframes.
    """

    keyframe_index: int
    landmark_ids: np.ndarray     # (M,) int64
    positions: np.ndarray        # (M,3) float64
    descriptors: np.ndarray      # (M,32) uint8
    keyframe_poses: dict[int, np.ndarray] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    # line landmarks of the local map (issue 4; empty without lines): endpoints A, B in world
    line_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))              # (L,)
    line_endpoints: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))          # (L,2,3)
    line_descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))  # (L,32)
    loop_epoch: int = 0          # loop corrections applied to the map so far (issue 10)

    def __len__(self) -> int:
        return len(self.landmark_ids)


# --- remote inspection (launcher <-> remote clients) -------------------------------
# Published on the inspection endpoint next to every actor event, and the request/reply
# channel beside it (see actors/inspection.py). INSPECT_SCHEMA is bumped on any change here.

INSPECT_SCHEMA = 2   # 2: map_delta replaces map_snapshot on the stream; inspect_frame; map, pause, resume,
                     #    save_map requests; map_saved events; frame read time on poses


@message("run_start")
class RunStart:
    """First event of a run on the inspection stream: which run this is."""
    run_id: str
    dataset: str
    source: str
    n_frames: int
    clock: str
    started_at: float            # wall time (s since the epoch)
    schema: int = INSPECT_SCHEMA


@message("run_end")
class RunEnd:
    """Last event of a run on the inspection stream."""
    run_id: str
    ok: bool
    reason: str
    wall_s: float


@message("map_delta")
class MapDelta:
    """Launcher → inspection clients, in place of ``map_snapshot``: the map points that are new or
    moved (by more than a tolerance) since the previous delta, and those removed; applied in
    ``seq`` order to an empty map they give the current map (the ``map`` request gives it whole).
    Keyframe poses are few: all of them, every time."""
    seq: int
    point_ids: np.ndarray         # (M,) int64, new or moved
    positions: np.ndarray         # (M, 3) float32
    removed_ids: np.ndarray       # (R,) int64
    n_points: int                 # map size once applied
    keyframe_indices: np.ndarray  # (K,) int64
    keyframe_poses: np.ndarray    # (K, 4, 4) T_world_cam
    final: bool = False


@message("inspect_frame")
class InspectFrame:
    """Launcher → inspection clients that subscribed to ``inspect_frame`` by name: a downscaled
    JPEG of the enhanced left image tracking used, at a capped rate."""
    index: int
    timestamp: float
    jpeg: bytes
    width: int
    height: int


@message("pause")
class Pause:
    """Supervisor → source: release no frame until ``resume``."""


@message("resume")
class Resume:
    """Supervisor → source: release frames again (realtime: the clock skips the pause)."""


@message("save_map_request")
class SaveMapRequest:
    """Supervisor → local mapping: write the map as it is now to ``path`` (canopy.loop.map_io)."""
    path: str


@message("map_saved")
class MapSaved:
    """Local mapping → supervisor (and inspection clients): the outcome of a ``save_map`` request."""
    path: str
    ok: bool
    keyframes: int = 0
    points: int = 0
    error: str = ""


@message("inspect_request")
class InspectRequest:
    """Client → launcher: ``command`` is one of status, config, stats, map, pause, resume,
    save_map, stop (actors.inspection.COMMANDS)."""
    command: str
    request_id: int = 0


@message("inspect_reply")
class InspectReply:
    """Launcher → client: the answer to one request (``error`` set when ``ok`` is False)."""
    request_id: int
    ok: bool
    run_id: str = ""
    payload: dict = field(default_factory=dict)
    error: str = ""
# --- local mapping <-> loop closing (issue 10) --------------------------------------

@message("loop_keyframe")
class LoopKeyframe:
    """Local mapping → loop closing: what place recognition needs of one keyframe.

    Row i describes left keypoint i (as in ``KeyframeData``); ``landmark_ids[i]`` is the
    map landmark it observes after insertion (-1: none), which gives covisibility.
    ``window_poses`` are the poses local BA just refined (keyframe index → T_world_cam), so
    the pose graph starts from the map as it is now.
    """

    index: int
    timestamp: float
    T_world_cam: np.ndarray      # (4,4)
    uv: np.ndarray               # (N,2) float32
    u_right: np.ndarray          # (N,) float32, -1 where no stereo match
    depth: np.ndarray            # (N,) float32, -1 where no stereo match
    octave: np.ndarray           # (N,) int32
    descriptors: np.ndarray      # (N,32) uint8
    landmark_ids: np.ndarray     # (N,) int64
    window_poses: dict[int, np.ndarray] = field(default_factory=dict)
    line_segments: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.float32))
    line_descriptors: np.ndarray = field(default_factory=lambda: np.zeros((0, 32), np.uint8))
    sent_at: float = 0.0
    # (N,3) float64 world position of landmark_ids[i] now (NaN where none): the full BA starts there
    landmark_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    loop_epoch: int = 0          # loop corrections local mapping had applied when it sent this


@message("loop_result")
class LoopResult:
    """Loop closing → local mapping (one per keyframe; the supervisor gets the closed ones).

    When ``closed``, ``corrections[k]`` is the world-frame correction C = T'_wc T_wc^-1 of
    keyframe ``keyframe_ids[k]`` after pose-graph optimisation; keyframes not listed ride
    with the nearest older listed one, landmarks with their reference keyframe.
    """

    keyframe_index: int
    closed: bool = False
    candidate: int = -1
    n_inliers: int = 0
    keyframe_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    corrections: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    loops: int = 0               # loops closed so far in this run
    timings_ms: dict = field(default_factory=dict)
    sent_at: float = 0.0
    # landmark fusion across the loop: (F,2) rows (duplicate, kept) to merge in the map
    fused: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    # a full bundle adjustment's answer (not a new loop): ``corrections`` as above for the
    # keyframes it optimised, and the optimised positions of its landmarks
    global_ba: bool = False
    landmark_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    landmark_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
