"""The realtime drop rule: skip a stale frame only when a newer one waits."""
from actors.backlog import FrameBacklog, max_frame_age
from protocol.messages import EndOfStream, FrameHandle


def _frame(i, sent_at):
    return FrameHandle(index=i, timestamp=i * 0.05, ring="r", slot=i % 4, generation=2, sent_at=sent_at)


def test_lockstep_never_drops():
    q = FrameBacklog(max_frame_age("lockstep", 0.05))
    for i in range(5):
        q.push(_frame(i, sent_at=0.0))
    got = [q.pop(now=100.0) for _ in range(5)]
    assert [h.index for h, _ in got] == [0, 1, 2, 3, 4]
    assert sum(d for _, d in got) == 0


def test_burst_of_fresh_frames_is_processed_in_order():
    q = FrameBacklog(max_frame_age("realtime", 0.05))
    q.push(_frame(0, sent_at=10.00))
    q.push(_frame(1, sent_at=10.01))  # the source was late: two frames arrive together
    h, dropped = q.pop(now=10.03)
    assert (h.index, dropped) == (0, 0)
    h, dropped = q.pop(now=10.06)
    assert (h.index, dropped) == (1, 0)  # the last frame is never dropped


def test_stale_frames_are_skipped_when_newer_waits():
    q = FrameBacklog(max_frame_age("realtime", 0.05))
    for i, t in enumerate([10.0, 10.05, 10.10, 10.15]):
        q.push(_frame(i, sent_at=t))
    h, dropped = q.pop(now=10.13)  # frames 0 and 1 are > 50 ms old and newer ones wait
    assert (h.index, dropped) == (2, 2)
    h, dropped = q.pop(now=10.30)  # alone in the queue: processed however old
    assert (h.index, dropped) == (3, 0)
    assert q.pop(now=10.3) == (None, 0)


def test_end_of_stream_waits_for_the_frames():
    q = FrameBacklog(None)
    q.push(_frame(0, 0.0))
    assert q.push(EndOfStream(n_frames=1)) and q.has_work()
    assert q.pop()[0].index == 0
    assert q.has_work() and q.end.n_frames == 1 and q.pop() == (None, 0)
    assert not q.push("something else")
