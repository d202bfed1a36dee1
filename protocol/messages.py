"""Every message that crosses a process boundary, defined once.

Frames never travel here on one host: a ``FrameHandle`` names a slot of a
shared-memory ring and the slot's generation, so a reader can tell that the
slot was overwritten under it (see ``shared.ring``). Only what the receiver
needs is sent (pySLAM's explicit cross-process messages), never a live map.
"""
from __future__ import annotations

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
    status: str               # "init" | "ok" | "lost"
    n_inliers: int
    n_matches: int
    is_keyframe: bool
    ref_keyframe: int
    T_ref_cam: np.ndarray
    timings_ms: dict = field(default_factory=dict)
    sent_at: float = 0.0


@message("map_snapshot")
class MapSnapshot:
    """Local mapping → supervisor: keyframe poses and map points so far."""
    keyframe_indices: np.ndarray   # (K,) int64 frame indices
    keyframe_stamps: np.ndarray    # (K,)
    keyframe_poses: np.ndarray     # (K, 4, 4) T_world_cam
    points: np.ndarray             # (N, 3) float32
    final: bool = False
    timings_ms: dict = field(default_factory=dict)
