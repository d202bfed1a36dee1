"""Typed parameters of line features (one frozen dataclass, YAML section ``lines``).

Detection (AGRI §3.2.1 uses LSD; OpenCV's FastLineDetector is the faster alternative),
LBD description (Zhang & Koch 2013, OpenCV contrib ``line_descriptor`` defaults) and
stereo line matching on rectified pairs (AGRI §3.2.2; PL-SLAM's stereo line search).
Build from YAML with ``shared.params.params_from_mapping(LineParams, section, source)``.
"""
from __future__ import annotations

from dataclasses import dataclass

from shared.errors import ConfigError

DETECTORS = ("fld", "lsd")


@dataclass(frozen=True)
class LineParams:
    # --- detection --------------------------------------------------------------------
    detector: str = "fld"                # "fld" (cv2.ximgproc FastLineDetector) or "lsd"
    min_length_fraction: float = 0.02    # of the image diagonal (18 px at 752x480)
    max_lines: int = 300                 # keep the longest segments
    fld_distance_threshold: float = 1.41421356  # px, FLD default (sqrt 2)
    fld_canny_low: float = 50.0          # FLD defaults
    fld_canny_high: float = 50.0
    fld_canny_aperture: int = 3
    fld_merge: bool = False
    lsd_scale: float = 0.8               # LSD defaults (von Gioi et al. 2008)
    lsd_sigma_scale: float = 0.6
    lsd_angle_tolerance_deg: float = 22.5
    lsd_density: float = 0.7
    # the image border (px) where endpoints count as outside the image
    border_tolerance: float = 0.5

    # --- LBD description (OpenCV BinaryDescriptor defaults) ---------------------------
    lbd_band_width: int = 7              # rows per band; 9 bands across the line
    lbd_reduction_ratio: int = 2

    # --- stereo matching on rectified rows ----------------------------------------------
    stereo_max_hamming: int = 70         # of 256 bits
    stereo_ratio: float = 0.85           # best / second-best Hamming distance
    min_disparity: float = 0.5           # px, at both endpoints
    max_disparity_fraction: float = 0.5  # of the image width
    min_vertical_overlap: float = 0.5    # shared row range / shorter row range of the pair
    max_angle_diff_deg: float = 10.0     # directed angles (LSD/FLD orient by gradient polarity)
    min_angle_from_horizontal_deg: float = 15.0  # flatter lines have no reliable disparity

    def validate(self) -> "LineParams":
        def need(ok: bool, name: str, what: str) -> None:
            if not ok:
                raise ConfigError("LineParams", f"{name} {what} (got {getattr(self, name)!r})")

        need(self.detector in DETECTORS, "detector", f"must be one of {DETECTORS}")
        need(0 < self.min_length_fraction < 1, "min_length_fraction", "must be in (0, 1)")
        need(self.max_lines > 0, "max_lines", "must be > 0")
        need(self.fld_distance_threshold > 0, "fld_distance_threshold", "must be > 0")
        need(0 < self.fld_canny_low <= self.fld_canny_high, "fld_canny_low", "must be in (0, fld_canny_high]")
        need(self.fld_canny_aperture in (0, 3, 5, 7), "fld_canny_aperture", "must be 0, 3, 5 or 7")
        need(0 < self.lsd_scale <= 1, "lsd_scale", "must be in (0, 1]")
        need(self.lsd_sigma_scale > 0, "lsd_sigma_scale", "must be > 0")
        need(0 < self.lsd_angle_tolerance_deg < 90, "lsd_angle_tolerance_deg", "must be in (0, 90)")
        need(0 < self.lsd_density <= 1, "lsd_density", "must be in (0, 1]")
        need(self.border_tolerance >= 0, "border_tolerance", "must be >= 0")
        need(self.lbd_band_width >= 3 and self.lbd_band_width % 2 == 1, "lbd_band_width", "must be odd and >= 3")
        need(self.lbd_reduction_ratio >= 1, "lbd_reduction_ratio", "must be >= 1")
        need(0 <= self.stereo_max_hamming <= 256, "stereo_max_hamming", "must be in [0, 256]")
        need(0 < self.stereo_ratio <= 1, "stereo_ratio", "must be in (0, 1]")
        need(self.min_disparity > 0, "min_disparity", "must be > 0")
        need(0 < self.max_disparity_fraction <= 1, "max_disparity_fraction", "must be in (0, 1]")
        need(0 < self.min_vertical_overlap <= 1, "min_vertical_overlap", "must be in (0, 1]")
        need(0 < self.max_angle_diff_deg < 90, "max_angle_diff_deg", "must be in (0, 90)")
        need(0 <= self.min_angle_from_horizontal_deg < 90, "min_angle_from_horizontal_deg", "must be in [0, 90)")
        return self

    def __post_init__(self):
        self.validate()
