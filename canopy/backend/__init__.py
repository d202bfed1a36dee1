"""Local mapping back end (AGRI-SLAM §3.3): keyframes, landmarks, local BA in GTSAM, culling."""
from canopy.backend.local_mapper import Keyframe, Landmark, LocalMapper
from canopy.backend.params import MappingParams

__all__ = ["Keyframe", "Landmark", "LocalMapper", "MappingParams"]
