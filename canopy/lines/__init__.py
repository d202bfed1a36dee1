"""Line features (AGRI-SLAM §3.2.1-3.2.2, §3.3.2 Eq. 10): detection, LBD description,
stereo line matching with endpoint triangulation, and the line reprojection error."""
from canopy.lines.features import LineDescriber, describe_segments, detect_segments, sanitize_segments, segment_lengths
from canopy.lines.geometry import (line_coefficients, line_reprojection_error, line_reprojection_jacobians,
                                   line_residuals)
from canopy.lines.params import LineParams
from canopy.lines.stereo import (StereoLines, backproject, match_stereo_lines, right_segments_in_reach,
                                 stereo_candidates)

__all__ = ["LineParams", "detect_segments", "describe_segments", "LineDescriber", "sanitize_segments",
           "segment_lengths", "match_stereo_lines", "stereo_candidates", "right_segments_in_reach", "StereoLines",
           "backproject", "line_coefficients", "line_residuals", "line_reprojection_error",
           "line_reprojection_jacobians"]
