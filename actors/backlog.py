"""Frames waiting for an actor, and the realtime rule for dropping them.

A live camera does not wait for a slow consumer. In ``realtime`` a frame is
dropped (and counted) when it is older than ``max_age_s`` while a newer frame
is already waiting: the consumer skips ahead instead of falling further
behind. Otherwise frames are handled in order, so a short hiccup (two frames
arriving together because the source was late) costs latency, not frames.
In ``lockstep`` nothing is ever dropped.
"""
from __future__ import annotations

import time
from collections import deque

from protocol.messages import EndOfStream, FrameHandle


class FrameBacklog:
    def __init__(self, max_age_s: float | None):
        self.max_age_s = max_age_s
        self._frames: deque[FrameHandle] = deque()
        self.end: EndOfStream | None = None

    def push(self, msg) -> bool:
        """Queue a FrameHandle or an EndOfStream; False for anything else."""
        if isinstance(msg, FrameHandle):
            self._frames.append(msg)
            return True
        if isinstance(msg, EndOfStream):
            self.end = msg
            return True
        return False

    def __len__(self) -> int:
        return len(self._frames)

    def has_work(self) -> bool:
        return bool(self._frames) or self.end is not None

    def pop(self, now: float | None = None) -> tuple[FrameHandle | None, int]:
        """The next frame to process and how many stale frames were skipped."""
        dropped = 0
        if self.max_age_s is not None:
            now = time.time() if now is None else now
            while len(self._frames) > 1 and now - self._frames[0].sent_at > self.max_age_s:
                self._frames.popleft()
                dropped += 1
        return (self._frames.popleft() if self._frames else None), dropped


def max_frame_age(clock: str, frame_period_s: float, periods: float = 1.0) -> float | None:
    """How stale a frame may get before it is skipped (None in lockstep)."""
    return None if clock == "lockstep" else periods * frame_period_s
