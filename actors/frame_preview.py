"""Downscaled JPEG previews of the frames tracking saw, for remote viewers (issue 12).

Read in the launcher from the enhanced frame ring in shared memory (the frame a pose belongs to is
still there: the ring holds several frames), so no actor changes and no image crosses ZeroMQ on
one host. Used by the Foxglove live view and the inspection stream's ``inspect_frame`` events.
"""
from __future__ import annotations

import cv2
import numpy as np

IMAGE_MAX_WIDTH = 376           # half a EuRoC frame: enough to see what tracking saw, ~10 kB JPEG
JPEG_QUALITY = 70


def jpeg_preview(image: np.ndarray, max_width: int = IMAGE_MAX_WIDTH, quality: int = JPEG_QUALITY) -> bytes:
    """Downscaled JPEG of a grey or BGR image (INTER_AREA: no aliasing when shrinking)."""
    h, w = image.shape[:2]
    if w > max_width:
        image = cv2.resize(image, (max_width, max(1, round(h * max_width / w))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()


class RingFrames:
    """The enhanced left image of frame ``index``, read from the frame ring in shared memory
    (None when the slot was overwritten since: the live view skips that image)."""

    def __init__(self, ring_name: str):
        self.ring_name = ring_name
        self.ring = None

    def __call__(self, index: int) -> np.ndarray | None:
        from shared.ring import FrameRing, SlotOverwritten

        if self.ring is None:
            try:
                self.ring = FrameRing.attach(self.ring_name)
            except Exception:
                return None
        hit = np.flatnonzero(self.ring.slots["index"] == index)
        if not len(hit):
            return None
        slot = int(hit[0])
        generation = int(self.ring.slots["generation"][slot])
        if generation % 2:  # odd: being written
            return None
        try:
            _, _, images = self.ring.read(slot, generation)
        except SlotOverwritten:
            return None
        return images[0]

    def close(self) -> None:
        if self.ring is not None:
            self.ring.close()
            self.ring = None
