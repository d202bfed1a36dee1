"""Shared-memory frame ring: generations, overwrite detection, clean unlink."""
import os
import subprocess
import sys

import numpy as np
import pytest

from shared.errors import InputError
from shared.ring import FrameRing, SlotOverwritten


@pytest.fixture
def ring():
    r = FrameRing.create(f"canopy_test_{os.getpid()}", n_slots=3, height=48, width=64)
    yield r
    r.close()
    r.unlink()
    assert not os.path.exists(f"/dev/shm/{r.name}")


def _pair(v):
    return [np.full((48, 64), v, np.uint8), np.full((48, 64), 255 - v, np.uint8)]


def test_reader_in_another_mapping_sees_written_frame(ring):
    reader = FrameRing.attach(ring.name)
    slot, gen = ring.write(5, 0.25, _pair(10))
    index, stamp, (left, right) = reader.read(slot, gen)
    assert (index, stamp) == (5, 0.25)
    assert left[0, 0] == 10 and right[0, 0] == 245
    assert gen % 2 == 0  # even generation = complete slot
    reader.close()


def test_overwritten_slot_is_detected(ring):
    slot, gen = ring.write(0, 0.0, _pair(1))
    for i in range(3):  # a whole ring later the slot holds another frame
        ring.write(i + 1, 0.0, _pair(2))
    with pytest.raises(SlotOverwritten):
        ring.read(slot, gen)


def test_view_reads_in_place_and_holds_tells_an_overwrite(ring):
    """The enhancement actor reads the raw slot through ``view`` (no copy) and keeps what it
    computed only if ``holds`` is still true afterwards."""
    reader = FrameRing.attach(ring.name)
    slot, gen = ring.write(7, 0.5, _pair(10))
    index, stamp, (left, right) = reader.view(slot, gen)
    assert (index, stamp) == (7, 0.5) and left[0, 0] == 10 and right[0, 0] == 245
    assert not left.flags.writeable            # another actor's slot: read only
    assert reader.holds(slot, gen)
    for i in range(3):                         # a whole ring later the slot holds another frame
        ring.write(i + 8, 0.0, _pair(20))
    assert left[0, 0] == 20                    # a view, not a copy: it sees the overwrite ...
    assert not reader.holds(slot, gen)         # ... and holds() says so
    with pytest.raises(SlotOverwritten):
        reader.view(slot, gen)
    with pytest.raises(InputError, match="out of range"):
        reader.view(3, gen)
    del left, right
    reader.close()


def test_wrong_image_size_names_the_frame(ring):
    with pytest.raises(InputError, match="frame 9"):
        ring.write(9, 0.0, [np.zeros((10, 10), np.uint8)] * 2)


def test_attach_to_missing_ring_is_a_clear_error():
    with pytest.raises(InputError, match="not found"):
        FrameRing.attach("canopy_no_such_ring")


def test_attaching_process_exit_does_not_unlink_the_ring(ring):
    """Python 3.11's resource tracker would unlink a segment when an attaching
    process exits; our attach path must not register it."""
    ring.write(3, 1.0, _pair(7))
    code = ("from shared.ring import FrameRing\n"
            f"r = FrameRing.attach({ring.name!r})\n"
            "print(int(r.slots['index'][0]))\nr.close()\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                         cwd=os.path.dirname(os.path.dirname(__file__)))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "3"
    assert "leaked" not in out.stderr
    assert os.path.exists(f"/dev/shm/{ring.name}")
