"""Line features inside ``Tracker`` (AGRI §3.2.1-3.2.2; issue 4): the line worker jobs, the
line-landmark view and the line fields of a keyframe.

A mixin of ``canopy.frontend.tracker.Tracker``: the state it uses (``_line_pool``,
``_line_update_view``, ``_line_provisional``...) is created in ``Tracker.__init__`` when
``TrackingParams.use_lines`` is on; nothing here runs otherwise.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING

import cv2
import numpy as np

from canopy.frontend.geometry import transform
from shared.arrays import unique_sorted
from shared.types import StereoFrame

if TYPE_CHECKING:
    from canopy.frontend.line_tracking import LineFrame


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


class TrackerLinesMixin:
    """Line jobs and line keyframe fields of the tracker (see the module docstring)."""

    def _line_map_view(self):
        if self._line_view_dirty:
            parts = [(self._line_update_view.ids, self._line_update_view.endpoints, self._line_update_view.desc)]
            parts += [self._line_provisional[k] for k in sorted(self._line_provisional)]
            ids = np.concatenate([q[0] for q in parts])
            _, first = np.unique(ids, return_index=True)
            first = np.sort(first)
            self._line_view.set(ids[first], np.concatenate([q[1] for q in parts])[first],
                                np.concatenate([q[2] for q in parts])[first])
            self._line_view_dirty = False
        return self._line_view

    def _detect_lines(self, image: np.ndarray, left=None) -> LineFrame:
        """Segments + LBD of one image (AGRI §3.2.1), in the line worker.

        ``left`` (the left image's LineFrame, or the future of it queued before this job in the
        same worker) marks a right image: only its segments within stereo reach of a left
        segment (``right_segments_in_reach``) are kept and described; the others could never
        be matched.
        """
        t0 = time.perf_counter()
        scale = self.params.line_image_scale
        if scale != 1.0:  # detect and describe on a reduced image, endpoints back in full-size pixels
            image = cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        segs, stats = self._detect_segments(image, self.line_params)
        # full-size pixels: pixel centres of the INTER_AREA grid above
        full = (segs.astype(np.float64) + 0.5) / scale - 0.5 if scale != 1.0 else segs.astype(np.float64)
        if left is not None:
            left = left.result() if hasattr(left, "result") else left
            keep = self._right_in_reach(left.segs, full, self.calib, self.line_params)
            segs, full = segs[keep], full[keep]
            stats["out_of_reach"] = int((~keep).sum())
        t1 = time.perf_counter()
        desc = (self._line_describer if left is None else self._line_describer_right)(image, segs)
        stats["detect_ms"] = (t1 - t0) * 1e3
        stats["describe_ms"] = _ms(t1)
        return self._lt.LineFrame.build(full, desc, stats)

    def _keyframe_likely(self) -> bool:
        """Whether this frame may well become a keyframe: (re)initialisation, right after a
        keyframe (keyframes come in runs when the view changes fast, as on KITTI), or the
        frame where ``max_frames_between_keyframes`` forces one."""
        return (not self._initialised or self._need_restart or self._last_was_keyframe
                or self._frames_since_kf + 1 >= self.params.max_frames_between_keyframes)

    def _submit_line_jobs(self, frame: StereoFrame):
        """Queue the left image's lines and, when a keyframe is likely, the right image's (needed
        only by keyframes) in the line worker; returns the left job. The right lines are a pure
        function of the right image, so whether they were computed ahead or on demand never
        changes a result."""
        job = self._line_pool.submit(self._detect_lines, frame.left)
        if self._keyframe_likely():
            self._right_lines_job = (frame.index, self._line_pool.submit(self._detect_lines, frame.right, job))
        return job

    def _right_lines(self, frame: StereoFrame, lines: LineFrame) -> LineFrame:
        """The right image's lines: the job queued ahead, or one queued now (in the same worker,
        so the right describer is never used by two threads)."""
        t0 = time.perf_counter()
        ahead = self._right_lines_job
        self._right_lines_job = None
        if ahead is not None and ahead[0] == frame.index:
            right = ahead[1].result()
            self._line_timings["lines_right_wait"] = _ms(t0)
        else:
            right = self._line_pool.submit(self._detect_lines, frame.right, lines).result()
            self._line_timings["lines_right_on_demand"] = _ms(t0)
        return right

    def _finish_line_jobs(self, is_keyframe: bool) -> None:
        """Drop a right-image job queued for a frame that did not become a keyframe."""
        self._last_was_keyframe = bool(is_keyframe)
        if self._right_lines_job is not None:
            self._right_lines_job[1].cancel()  # no-op if already running: it finishes on its own
            self._right_lines_job = None

    def _keyframe_lines(self, frame: StereoFrame, lines: LineFrame, line_matched: np.ndarray, T_wc: np.ndarray) -> dict:
        """Line fields of the keyframe: matched map lines plus new stereo lines (AGRI §3.2.2).

        The right image's lines are needed only here (stereo lines only at keyframes): queued
        ahead in the line worker when a keyframe was likely, else now. New lines are stereo
        matches not matched to a map line, with both endpoints in front and closer than
        ``line_max_depth_baselines`` baselines.
        """
        n = len(lines)
        right = self._right_lines(frame, lines)
        st = self._match_stereo_lines(lines.segs, lines.desc, right.segs, right.desc, self.calib, self.line_params)
        seg_r = np.full((n, 4), np.nan)
        P_cam = np.full((n, 2, 3), np.nan)
        seg_r[st.left_idx] = right.segs[st.right_idx]
        P_cam[st.left_idx] = st.points_cam
        z = P_cam[:, :, 2]
        with np.errstate(invalid="ignore"):
            stereo_ok = np.isfinite(z).all(axis=1) & (z > 0).all(axis=1) & (z < self._line_max_depth).all(axis=1)
        create = stereo_ok & (line_matched < 0)
        idx = np.flatnonzero(create)
        new_ids = np.full(n, -1, np.int64)
        new_ids[idx] = self._next_line_id + np.arange(len(idx))
        self._next_line_id += len(idx)
        ends_w = transform(T_wc, P_cam[idx].reshape(-1, 3)).reshape(-1, 2, 3)
        self._line_provisional[frame.index] = (new_ids[idx], ends_w, lines.desc[idx])
        self._line_view_dirty = True
        rows = np.flatnonzero((line_matched >= 0) | create)
        self._ref_line_ids = unique_sorted(np.concatenate([line_matched[line_matched >= 0], new_ids[idx]]))
        return dict(line_segments=lines.segs[rows].astype(np.float32),
                    line_segments_right=seg_r[rows].astype(np.float32),
                    line_descriptors=lines.desc[rows].copy(), line_ids=line_matched[rows].copy(),
                    new_line_ids=new_ids[rows], line_endpoints_cam=P_cam[rows])

