"""Tracking front end (AGRI-SLAM §3.2): ORB, stereo matching, map tracking, keyframes."""
from canopy.frontend.cell_extractor import CellExtractor, make_extractor
from canopy.frontend.features import Features, OrbExtractor
from canopy.frontend.messages import KeyframeData, LocalMapUpdate, TrackingResult
from canopy.frontend.params import TrackingParams
from canopy.frontend.stereo import StereoMatches, match_stereo
from canopy.frontend.tracker import Tracker
from canopy.frontend.tracker_segments import STATUS_INIT, STATUS_LOST, STATUS_OK, STATUS_PREDICTED

__all__ = ["CellExtractor", "make_extractor", "Features", "OrbExtractor", "KeyframeData", "LocalMapUpdate", "TrackingResult", "TrackingParams",
           "StereoMatches", "match_stereo", "Tracker", "STATUS_INIT", "STATUS_OK", "STATUS_LOST",
           "STATUS_PREDICTED"]
