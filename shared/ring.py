"""A ring of shared-memory slots holding stereo frames.

Images never travel through ZeroMQ on one host: the launcher creates a ring,
writers copy a frame into the next slot and send only ``(slot, generation)``.
Each slot has a generation counter used as a seqlock: the writer makes it odd
while writing and even when the slot is complete. A reader copies the images
and checks that the generation it was promised is still there before and
after the copy; if not, the slot was overwritten under it (the reader fell a
whole ring behind) and the frame counts as dropped.

Ownership: the creator (the supervisor) unlinks the segment. Other processes
attach by mapping ``/dev/shm/<name>`` directly instead of through
``multiprocessing.shared_memory``: on Python 3.11 an attaching
``SharedMemory`` registers the segment with the resource tracker, which then
unlinks it when that process exits (or warns about a "leak" it does not own).
The creator keeps its tracker registration as a safety net: if the
supervisor itself is killed, the tracker still removes the segment.
"""
from __future__ import annotations

import mmap
import os
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

from shared.errors import InputError

_MAGIC = 0x43414E4F50590001  # "CANOPY" + layout version 1
_META = np.dtype([("magic", "<u8"), ("n_slots", "<i8"), ("height", "<i8"), ("width", "<i8"),
                  ("n_images", "<i8"), ("writes", "<u8"), ("pad", "<u8", 2)])
_SLOT = np.dtype([("generation", "<u8"), ("index", "<i8"), ("timestamp", "<f8"), ("pad", "<u8")])
_SHM_DIR = "/dev/shm"


class SlotOverwritten(Exception):
    """The slot no longer holds the generation the handle promised."""


@dataclass(frozen=True)
class RingLayout:
    n_slots: int
    height: int
    width: int
    n_images: int = 2

    @property
    def image_bytes(self) -> int:
        return self.height * self.width

    @property
    def slot_bytes(self) -> int:
        return self.n_images * self.image_bytes

    @property
    def data_offset(self) -> int:
        header = _META.itemsize + self.n_slots * _SLOT.itemsize
        return (header + 63) // 64 * 64  # cache-line align the pixels

    @property
    def total_bytes(self) -> int:
        return self.data_offset + self.n_slots * self.slot_bytes


class FrameRing:
    """Writer and reader view of one ring. Use ``create`` or ``attach``."""

    def __init__(self, name: str, buf, layout: RingLayout, owner_shm=None, mapping=None):
        self.name = name
        self.layout = layout
        self._shm = owner_shm
        self._mmap = mapping
        self._buf = buf
        self.meta = np.frombuffer(buf, dtype=_META, count=1, offset=0)
        self.slots = np.frombuffer(buf, dtype=_SLOT, count=layout.n_slots, offset=_META.itemsize)
        self.pixels = np.frombuffer(buf, dtype=np.uint8, count=layout.n_slots * layout.slot_bytes,
                                    offset=layout.data_offset).reshape(
            layout.n_slots, layout.n_images, layout.height, layout.width)
        self._next_slot = 0

    # --- construction -------------------------------------------------------------
    @classmethod
    def create(cls, name: str, n_slots: int, height: int, width: int, n_images: int = 2) -> "FrameRing":
        if n_slots < 2 or height < 1 or width < 1 or n_images < 1:
            raise ValueError(f"bad ring layout {n_slots}x{n_images}x{height}x{width}")
        layout = RingLayout(n_slots, height, width, n_images)
        shm = shared_memory.SharedMemory(name=name, create=True, size=layout.total_bytes)
        ring = cls(name, shm.buf, layout, owner_shm=shm)
        ring.meta[0] = (_MAGIC, n_slots, height, width, n_images, 0, (0, 0))
        ring.slots["generation"] = 0
        ring.slots["index"] = -1
        return ring

    @classmethod
    def attach(cls, name: str) -> "FrameRing":
        path = os.path.join(_SHM_DIR, name)
        try:
            fd = os.open(path, os.O_RDWR)
        except FileNotFoundError:
            raise InputError(path, "shared-memory ring not found (was the supervisor stopped?)") from None
        try:
            size = os.fstat(fd).st_size
            mapping = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        meta = np.frombuffer(mapping, dtype=_META, count=1)[0]
        if int(meta["magic"]) != _MAGIC:
            mapping.close()
            raise InputError(path, "not a Canopy frame ring (bad magic)")
        layout = RingLayout(int(meta["n_slots"]), int(meta["height"]), int(meta["width"]), int(meta["n_images"]))
        if layout.total_bytes > size:
            mapping.close()
            raise InputError(path, f"ring is {size} bytes, layout needs {layout.total_bytes}")
        del meta
        return cls(name, mapping, layout, mapping=mapping)

    # --- writing ------------------------------------------------------------------
    def write(self, index: int, timestamp: float, images) -> tuple[int, int]:
        """Copy ``images`` into the next slot; return ``(slot, generation)``."""
        lay = self.layout
        if len(images) != lay.n_images:
            raise InputError(f"frame {index}", f"expected {lay.n_images} images, got {len(images)}")
        for img in images:
            if img.dtype != np.uint8 or img.shape != (lay.height, lay.width):
                raise InputError(f"frame {index}",
                                 f"image is {img.dtype} {img.shape}, the ring holds uint8 {(lay.height, lay.width)}")
        slot = self._next_slot
        self._next_slot = (slot + 1) % lay.n_slots
        rec = self.slots[slot:slot + 1]
        gen = int(rec["generation"][0]) + 1  # odd: being written
        rec["generation"] = gen
        for k, img in enumerate(images):
            self.pixels[slot, k] = img
        rec["index"] = index
        rec["timestamp"] = timestamp
        gen += 1  # even: complete
        rec["generation"] = gen
        self.meta["writes"] += 1
        return slot, gen

    # --- reading ------------------------------------------------------------------
    def read(self, slot: int, generation: int) -> tuple[int, float, list[np.ndarray]]:
        """Copy out the frame in ``slot`` if it still holds ``generation``."""
        if not 0 <= slot < self.layout.n_slots:
            raise InputError(f"ring {self.name}", f"slot {slot} out of range 0..{self.layout.n_slots - 1}")
        rec = self.slots[slot:slot + 1]
        if int(rec["generation"][0]) != generation:
            raise SlotOverwritten(f"slot {slot} holds generation {int(rec['generation'][0])}, wanted {generation}")
        images = [self.pixels[slot, k].copy() for k in range(self.layout.n_images)]
        index, stamp = int(rec["index"][0]), float(rec["timestamp"][0])
        if int(rec["generation"][0]) != generation:
            raise SlotOverwritten(f"slot {slot} was overwritten while being read")
        return index, stamp, images

    def view(self, slot: int, generation: int) -> tuple[int, float, list[np.ndarray]]:
        """Read-only views of the frame in ``slot`` (no copy) if it holds ``generation`` now.

        The writer may overwrite the slot under the views at any time: whatever is computed from
        them is valid only if ``holds(slot, generation)`` is still true after it (the seqlock's
        second check, done by the caller once it is finished with the pixels)."""
        if not 0 <= slot < self.layout.n_slots:
            raise InputError(f"ring {self.name}", f"slot {slot} out of range 0..{self.layout.n_slots - 1}")
        rec = self.slots[slot:slot + 1]
        if int(rec["generation"][0]) != generation:
            raise SlotOverwritten(f"slot {slot} holds generation {int(rec['generation'][0])}, wanted {generation}")
        images = [self.pixels[slot, k] for k in range(self.layout.n_images)]
        for img in images:
            img.flags.writeable = False   # the views only read another actor's slot
        return int(rec["index"][0]), float(rec["timestamp"][0]), images

    def holds(self, slot: int, generation: int) -> bool:
        """True if ``slot`` still holds ``generation`` (complete, not overwritten since)."""
        return int(self.slots["generation"][slot]) == generation

    # --- lifetime -----------------------------------------------------------------
    def close(self) -> None:
        # Views must go before the buffer can be released.
        self.meta = self.slots = self.pixels = None
        self._buf = None
        if self._mmap is not None:
            self._mmap.close()
            self._mmap = None
        if self._shm is not None:
            self._shm.close()

    def unlink(self) -> None:
        """Remove the segment (creator only). Safe to call twice."""
        if self._shm is not None:
            try:
                self._shm.unlink()
            except FileNotFoundError:
                pass
            self._shm = None


def remove_segment(name: str) -> bool:
    """Best-effort removal of a segment by name (supervisor clean-up path)."""
    try:
        os.unlink(os.path.join(_SHM_DIR, name))
        return True
    except FileNotFoundError:
        return False
