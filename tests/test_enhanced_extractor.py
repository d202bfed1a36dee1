"""The KITTI rule for frames the enhancement changed (issue 9, docs/notes/s12-dark.md): the cells
extractor when AFE's Eq. 18 threshold finds enough FAST corners in the enhanced image, cv2.ORB
when it finds (almost) none; off (``enhanced_cells_min_corners`` 0) every enhanced frame keeps
cv2.ORB exactly."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.enhanced_extractor import EnhancedCellsRule
from canopy.frontend.features import OrbExtractor
from canopy.frontend.params import TrackingParams
from canopy.frontend.track_health import image_noise_sigma
from canopy.sources import open_source
from shared.errors import ConfigError


@pytest.fixture(scope="module")
def textured():
    return open_source("kitti", max_frames=6).frame(5).left


def flat(image: np.ndarray) -> np.ndarray:
    """A washed-out, smoothed copy: no 3x3 contrast near AFE's thresholds (~25-35 grey levels)."""
    return cv2.GaussianBlur((image * 0.15 + 100).astype(np.uint8), (0, 0), 2.0)


def params(min_corners: int = 10) -> TrackingParams:
    return replace(TrackingParams(), extractor="cells", extractor_enhanced="opencv",
                   enhanced_cells_min_corners=min_corners, enhanced_cells_noise_factor=4.0)


def test_textured_enhanced_frame_goes_to_cells_with_noise_floor(textured):
    rule = EnhancedCellsRule(params())
    sigma = image_noise_sigma(textured)
    fb = rule.fallback(textured, 30, 3)
    assert rule.last_corners >= 10
    assert fb == max(3, int(np.ceil(4.0 * sigma)))
    feats = CellExtractor(params()).extract(textured, 30, 3)
    assert feats.extractor == "cells" and len(feats) > 500


def test_flat_enhanced_frame_keeps_opencv(textured):
    image = flat(textured)
    rule = EnhancedCellsRule(params())
    assert rule.fallback(image, 30, 3) is None and rule.last_corners < 10
    got = CellExtractor(params()).extract(image, 30, 3, 2000)
    want = OrbExtractor(params()).extract(image, 30, 3, 2000)
    assert got.extractor == "opencv"
    np.testing.assert_array_equal(got.uv, want.uv)
    np.testing.assert_array_equal(got.descriptors, want.descriptors)


def test_rule_off_keeps_opencv_on_every_enhanced_frame(textured):
    assert EnhancedCellsRule(params(0)).fallback(textured, 30, 3) is None
    got = CellExtractor(params(0)).extract(textured, 30, 3, 2000)
    want = OrbExtractor(params(0)).extract(textured, 30, 3, 2000)
    assert got.extractor == "opencv"
    np.testing.assert_array_equal(got.uv, want.uv)


def test_raw_frames_do_not_consult_the_rule(textured):
    """Frames the enhancement left alone (no AFE fallback) get the cells extractor as before."""
    a = CellExtractor(params()).extract(textured)
    b = CellExtractor(params(0)).extract(textured)
    np.testing.assert_array_equal(a.uv, b.uv)
    np.testing.assert_array_equal(a.descriptors, b.descriptors)


def test_smoothed_count_keeps_the_decision_over_a_flat_frame(textured):
    """With the moving average one flat frame in a textured sequence does not switch the extractor
    (hazy noisy sequences flicker between 0 and ~15 corners), a run of flat frames does."""
    p = replace(params(), enhanced_cells_corner_weight=0.2)
    rule = EnhancedCellsRule(p)
    assert rule.fallback(textured, 30, 3) is not None
    n_textured = rule.last_corners
    assert rule.fallback(flat(textured), 30, 3) is not None   # average 0.8 n, still >= 10
    assert rule.last_corners < 10 and rule.smoothed_corners == pytest.approx(0.8 * n_textured)
    decisions = [rule.fallback(flat(textured), 30, 3) for _ in range(40)]
    assert decisions[-1] is None
    per_frame = EnhancedCellsRule(params())   # weight 1: the newest image alone decides
    per_frame.fallback(textured, 30, 3)
    assert per_frame.fallback(flat(textured), 30, 3) is None


@pytest.mark.parametrize("field,value", [("enhanced_cells_min_corners", -1), ("enhanced_cells_noise_factor", -1),
                                         ("enhanced_cells_corner_weight", 0.0), ("enhanced_cells_corner_weight", 1.5)])
def test_bad_settings_are_rejected_by_name(field, value):
    with pytest.raises(ConfigError, match=field):
        replace(TrackingParams(), **{field: value})
