"""A control cell for KITTI g1-b0.06-high: the same DegradeParams and noise seed, but the right
camera's haze depth is the left SGBM depth (filled as the tool fills it) forward-warped by its
disparity (canopy.degrade.depth_from_rendered, view="right"), instead of SGBM on the mirrored pair:
the haze is then consistent between the two cameras wherever the left depth is (it keeps the left
image's own artefacts: the 128-px left band SGBM cannot match, filled from the row's first valid
disparity, and the holes filled from the farther neighbour).

    python docs/results/s9_haze/scripts/kitti_consistent_haze.py /tmp/s9haze/kitti_hh_consistent [noise seed, default 0]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[4]
sys.path.insert(0, str(ROOT))

import tools.degrade_sequence as ds  # noqa: E402
from canopy.degrade import depth_from_rendered, depth_from_stereo, grid_cells, ray_length  # noqa: E402


def consistent_rays(left, right, calib, params):
    z = depth_from_stereo(left, right, calib, params.max_depth, params.num_disparities, params.block_size, view="left")
    return [ray_length(depth_from_rendered(z, calib, params.max_depth, view=v), calib) for v in ("left", "right")]


ds._ray_maps = consistent_rays
cell = grid_cells((1.0,), (0.06,), ("high",), seed=int(sys.argv[2]) if len(sys.argv) > 2 else 0)[0]
print(ds.degrade_sequence("kitti", sys.argv[1], cell, force=True))
