"""Monocular mode (issue 13): ORB-SLAM-style two-view initialisation, monocular tracking
and local mapping with GTSAM projection factors. Stereo stays the default sensor."""
from canopy.mono.mapper import MonoMapper
from canopy.mono.params import MonoParams
from canopy.mono.tracker import MonoTracker
from canopy.mono.two_view import TwoViewResult, initialise_two_view

__all__ = ["MonoMapper", "MonoParams", "MonoTracker", "TwoViewResult", "initialise_two_view"]
