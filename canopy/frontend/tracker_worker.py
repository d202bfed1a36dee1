"""The right image on a worker thread (``TrackingParams.parallel_stereo``).

Tracking a stereo frame needs the left image's ORB features for everything, but the right
image only through the stereo matches (AGRI §3.2.2): they enter at the pose refinement (the
right-image column of each measurement) and the keyframe decision, not at the projection search
against the local map (ORB-SLAM's TrackWithMotionModel / SearchLocalPoints use the left
keypoints only). So one job on the worker thread extracts the right image's ORB, waits for the
left features, and matches stereo (band search, the SAD pyramids and sub-pixel refinement),
while the tracking thread extracts the left image and then searches the local map. OpenCV and
numpy release the GIL in their heavy calls, so on two cores the stereo matching leaves the
tracking thread's critical path. Every function is the serial path's: the result is identical
(``tests/test_tracking_speed.py``).
"""
from __future__ import annotations

import time
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from canopy.frontend.features import Features, OrbExtractor
from canopy.frontend.keypoint_centres import centre_keypoints
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import PairPyramids, StereoMatches, match_stereo
from shared.types import StereoCalibration, StereoFrame


def stage_clock() -> tuple[float, float]:
    """(wall, this thread's CPU) now: a stage's CPU time shows what it costs the critical path
    whatever the machine's load (wall time on a shared 2-core machine mostly measures waiting)."""
    return time.perf_counter(), time.thread_time()


def record_stage(timings: dict, name: str, t0: tuple[float, float]) -> None:
    """Record a stage's wall ms as ``name`` and its thread's CPU ms as ``name_cpu``."""
    timings[name] = (time.perf_counter() - t0[0]) * 1e3
    timings[name + "_cpu"] = (time.thread_time() - t0[1]) * 1e3


@dataclass
class ExtractedFrame:
    """A frame between ``Tracker.extract`` and ``Tracker.track_extracted``: its left features, its
    stereo matches (or the worker's pending ``StereoJob``), the left image's line job (None without
    lines), the noise sigma the FAST floor used, the stage timings so far and the (wall, CPU) clock
    at the start of ``extract``."""
    frame: StereoFrame
    left: Features
    stereo: Any          # StereoMatches | StereoJob
    line_job: Any        # Future | None
    noise_sigma: float | None
    timings: dict
    t_all: tuple[float, float]


def frame_stereo(left: Features, right: Features | None, frame: StereoFrame, calib: StereoCalibration,
                 params: TrackingParams, scale_factors: np.ndarray,
                 noise_sigma: float | None, pyramids: PairPyramids | None = None,
                 sensor_sigma: float | None = None) -> StereoMatches:
    """Stereo matches of one frame for the left features as OpenCV reports them (on an enhanced frame
    with the fill-in if the enhancement's noise sigma ``sensor_sigma`` opens its gate,
    ``stereo_fill.sensor_fill_open``); with
    ``centre_level_keypoints`` the right-image columns are mapped to pixel centres as the left
    keypoints are (``centre_keypoints``: per octave, so it needs the uncentred left features).
    ``pyramids``: the raw pair's ``PairPyramids`` if built ahead."""
    stereo = match_stereo(left, right, frame.left, frame.right, calib, params, noise_sigma, pyramids, sensor_sigma)
    if params.centre_level_keypoints:
        stereo = centre_keypoints(left, stereo, scale_factors, calib.width, calib.height)[1]
    return stereo


def raw_pair_likely(left: Features, params: TrackingParams) -> bool:
    """Whether the stereo refinement of a frame with these left features reads the raw pair's pyramids:
    it runs on the raw pair (``noisy_features.refinement_pair`` smooths it when the robust noise σ reaches
    ``subpixel_denoise_sigma``), or takes its vertex from it (``subpixel_raw_vertex_search``,
    ``stereo.raw_vertex``); True when that σ was not measured by the extractor."""
    sigma = left.robust_noise_sigma
    return (params.subpixel_denoise_sigma <= 0 or params.subpixel_raw_vertex_search > 0 or sigma is None
            or sigma < params.subpixel_denoise_sigma)


class StereoJob:
    """Right-image ORB + stereo matching of one frame on ``pool`` (one worker thread, so the
    right extractor is never used by two threads). Hand it the left features with
    ``set_left`` (or the left extraction's error with ``left_failed``, so the worker never
    waits forever); ``result()`` waits for the matches.

    ``prebuild``: build the pair's SAD pyramids (``PairPyramids``, ~3 ms of CPU on KITTI) after the
    right ORB, before waiting for the left keypoints: the refinement needs only the images, so
    this work leaves the stretch after the left ORB that the tracking thread waits on. Useful only
    when the refinement runs on the raw pair (not the smoothed one of a noisy frame,
    ``noisy_features.refinement_pair``); the caller predicts that from the last frame."""

    def __init__(self, pool: Executor, extractor: OrbExtractor, frame: StereoFrame, calib: StereoCalibration,
                 params: TrackingParams, scale_factors: np.ndarray, noise_sigma: float | None,
                 fast: tuple[int | None, int | None, int], prebuild: bool = False, sensor_sigma: float | None = None):
        self._left: Future = Future()
        self.timings: dict[str, float] = {}
        self._future = pool.submit(self._run, extractor, frame, calib, params, scale_factors, noise_sigma, fast,
                                   prebuild, sensor_sigma)

    def set_left(self, left: Features) -> None:
        self._left.set_result(left)

    def left_failed(self, error: BaseException) -> None:
        self._left.set_exception(error)

    def _run(self, extractor, frame, calib, params, scale_factors, noise_sigma, fast, prebuild,
             sensor_sigma) -> StereoMatches:
        t0 = stage_clock()
        # the flow matcher needs no right keypoints (canopy.frontend.stereo_flow)
        right = None if params.stereo_matcher == "flow" else extractor.extract(frame.right, *fast)
        record_stage(self.timings, "orb_right", t0)
        pyramids = None
        if prebuild and params.stereo_matcher != "flow":
            t0 = stage_clock()
            pyramids = PairPyramids.build(frame.left, frame.right, scale_factors)
            record_stage(self.timings, "stereo_pyramids", t0)
        left = self._left.result()
        t0 = stage_clock()
        stereo = frame_stereo(left, right, frame, calib, params, scale_factors, noise_sigma, pyramids, sensor_sigma)
        record_stage(self.timings, "stereo_worker", t0)
        return stereo

    def result(self) -> StereoMatches:
        return self._future.result()


class TrackerFeaturesMixin:
    """The left features and stereo matches of a frame, for ``canopy.frontend.tracker.Tracker``
    (uses its ``params``, ``calib``, ``scale_factors``, extractors, ``_pool`` and line jobs):
    serial, with only the right ORB in the worker (``parallel_extraction``), or with the whole
    right image in the worker (``parallel_stereo``, a pending ``StereoJob``)."""

    def _left_and_stereo(self, frame: StereoFrame, fast: tuple[int | None, int | None, int], noise_sigma,
                         timings: dict, sensor_sigma: float | None = None) -> tuple[Features, StereoMatches | StereoJob, object]:
        """(left features, stereo matches or the pending job, the left image's line job or None).
        ``sensor_sigma``: the enhancement's noise sigma of the frame (``frame_stereo``)."""
        t0 = stage_clock()
        if self._parallel_stereo:
            job = StereoJob(self._pool, self.extractor_right, frame, self.calib, self.params, self.scale_factors,
                            noise_sigma, fast, prebuild=getattr(self, "_stereo_raw_pair_hint", True),
                            sensor_sigma=sensor_sigma)
            try:
                left = self.extractor.extract(frame.left, *fast, noise_sigma=noise_sigma)
            except BaseException as error:
                job.left_failed(error)
                raise
            job.set_left(left)
            # the next frame's refinement is likely on the raw pair if this one's is (noise changes slowly)
            self._stereo_raw_pair_hint = raw_pair_likely(left, self.params)
            if self.params.centre_level_keypoints:  # OpenCV's pyramid coordinates -> pixel centres
                left = centre_keypoints(left, None, self.scale_factors, self.calib.width, self.calib.height)[0]
            record_stage(timings, "orb", t0)
            return left, job, None
        flow = self.params.stereo_matcher == "flow"  # no right keypoints (canopy.frontend.stereo_flow)
        if self._pool is not None and not flow:
            right_job = self._pool.submit(self.extractor_right.extract, frame.right, *fast)
        line_job = self._submit_line_jobs(frame) if self._lines_on else None
        # the tracker's noise sigma is of frame.left: the cell extractor's fallback floor reuses it
        left = self.extractor.extract(frame.left, *fast, noise_sigma=noise_sigma)
        if flow:
            right = None
        else:
            right = right_job.result() if self._pool is not None else self.extractor_right.extract(frame.right, *fast)
        record_stage(timings, "orb", t0)
        t0 = stage_clock()
        stereo = frame_stereo(left, right, frame, self.calib, self.params, self.scale_factors, noise_sigma,
                              sensor_sigma=sensor_sigma)
        if self.params.centre_level_keypoints:
            left = centre_keypoints(left, None, self.scale_factors, self.calib.width, self.calib.height)[0]
        record_stage(timings, "stereo", t0)
        return left, stereo, line_job
