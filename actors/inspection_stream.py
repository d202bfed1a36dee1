"""What the inspection stream publishes for each actor event (issue 12).

Most events go out as the actors sent them (poses, stats, loop results, errors, map_saved).
Two are changed on the way:

- ``map_snapshot`` (the whole map, twice a second) becomes a ``map_delta``: only the points new
  or moved by more than ``MOVE_TOLERANCE_M`` since the previous delta, and the ids removed. A
  client that applies the deltas in order holds the map; the ``map`` request gives it whole.
- a ``pose`` is followed by an ``inspect_frame`` (downscaled JPEG of the enhanced left image) at
  most ``FRAME_MAX_HZ`` times a second, and only once a client subscribed to ``inspect_frame`` by
  name (a client subscribed to everything does not make the launcher encode images).
"""
from __future__ import annotations

import time
from typing import Any, Callable, Iterator

import numpy as np

from actors.frame_preview import jpeg_preview
from protocol.codec import encode
from protocol.messages import FramePose, InspectFrame, MapDelta, MapSnapshot

MOVE_TOLERANCE_M = 1e-3     # a point moved less than this by BA is not re-sent
FRAME_MAX_HZ = 5.0
POSED_STATUSES = ("init", "ok", "predicted")


def snapshot_ids(snap: MapSnapshot) -> np.ndarray:
    """Landmark ids of a snapshot's points (positions when an older sender gave none)."""
    ids = np.asarray(snap.point_ids, np.int64).reshape(-1)
    n = len(np.asarray(snap.points).reshape(-1, 3))
    return ids if len(ids) == n else np.arange(n, dtype=np.int64)


class MapDeltaTracker:
    """Turns successive whole-map snapshots into deltas against what clients were last sent."""

    def __init__(self, tolerance_m: float = MOVE_TOLERANCE_M):
        self.tolerance_m = float(tolerance_m)
        self.ids = np.zeros(0, np.int64)              # sorted
        self.positions = np.zeros((0, 3), np.float32)  # row i: the position clients hold for ids[i]
        self.seq = 0

    def delta(self, snap: MapSnapshot) -> MapDelta:
        ids = snapshot_ids(snap)
        pts = np.asarray(snap.points, np.float32).reshape(-1, 3)
        order = np.argsort(ids, kind="stable")
        ids, pts = ids[order], pts[order]
        # where each current id sits among the ids last sent (vectorised set algebra on sorted ids)
        pos = np.searchsorted(self.ids, ids)
        known = pos < len(self.ids)
        known[known] = self.ids[pos[known]] == ids[known]
        moved = np.zeros(len(ids), bool)
        if known.any():
            moved[known] = np.linalg.norm(pts[known] - self.positions[pos[known]], axis=1) > self.tolerance_m
        send = ~known | moved
        removed = np.setdiff1d(self.ids, ids, assume_unique=True)
        # clients now hold: the old positions of unsent points, the new ones of sent points
        held = pts.copy()
        held[known & ~moved] = self.positions[pos[known & ~moved]]
        self.ids, self.positions = ids, held
        self.seq += 1
        return MapDelta(seq=self.seq, point_ids=ids[send], positions=pts[send], removed_ids=removed,
                        n_points=int(len(ids)), keyframe_indices=np.asarray(snap.keyframe_indices, np.int64),
                        keyframe_poses=np.asarray(snap.keyframe_poses, np.float64).reshape(-1, 4, 4),
                        final=bool(snap.final))


def apply_delta(held: dict[int, np.ndarray], delta: MapDelta) -> dict[int, np.ndarray]:
    """A client's side: update ``{landmark id: position}`` with one delta."""
    for i in np.asarray(delta.removed_ids).tolist():
        held.pop(int(i), None)
    for i, p in zip(np.asarray(delta.point_ids).tolist(), np.asarray(delta.positions)):
        held[int(i)] = p
    return held


class InspectStream:
    """Per event, the ``(kind, payload)`` pairs to publish. ``frames(index)`` gives the enhanced
    left image of a frame (or None); ``frames_wanted`` is set when a client subscribes to them."""

    def __init__(self, frames: Callable[[int], np.ndarray | None] | None = None,
                 frame_max_hz: float = FRAME_MAX_HZ, clock: Callable[[], float] = time.monotonic):
        self.frames = frames
        self.frames_wanted = False
        self.frame_period_s = 1.0 / frame_max_hz
        self.clock = clock
        self._last_frame_t = -np.inf
        self.map = MapDeltaTracker()

    def events(self, msg: Any, payload: bytes) -> Iterator[tuple[str, bytes]]:
        if isinstance(msg, MapSnapshot):
            yield MapDelta.KIND, encode(self.map.delta(msg))
            return
        yield msg.KIND, payload
        if isinstance(msg, FramePose) and self.frames_wanted and self.frames is not None \
                and msg.status in POSED_STATUSES:
            now = self.clock()
            if now - self._last_frame_t >= self.frame_period_s:
                image = self.frames(msg.index)
                if image is not None:
                    self._last_frame_t = now
                    jpeg = jpeg_preview(image)
                    h, w = _jpeg_size(image.shape[:2])
                    yield InspectFrame.KIND, encode(InspectFrame(index=msg.index, timestamp=msg.timestamp,
                                                                 jpeg=jpeg, width=w, height=h))


def _jpeg_size(shape: tuple[int, int]) -> tuple[int, int]:
    from actors.frame_preview import IMAGE_MAX_WIDTH

    h, w = shape
    return (h, w) if w <= IMAGE_MAX_WIDTH else (max(1, round(h * IMAGE_MAX_WIDTH / w)), IMAGE_MAX_WIDTH)
