"""ORB-SLAM3's 'tracked' frames on the project grid's KITTI g0.15-b0.06-high (seed 0) and the held-out g0.1-b0.03-high (seed 11)."""
import sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[3]))  # the repository root
from benchmarks.bench_degrade_grid import degraded_cell
from benchmarks.peers import orbslam3 as orb
from canopy.degrade import grid_cells
from canopy.sources import BUNDLED_DATA
for gain, beta, seed in ((0.15, 0.06, 0), (0.1, 0.03, 11)):
    cell = grid_cells((gain,), (beta,), ("high",), seed=seed)[0]
    path, _ = degraded_cell("kitti", "kitti", BUNDLED_DATA["kitti"], cell, None, Path("/tmp"), Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/heldout-cache"), "stereo")
    res = orb.run_stereo(str(path), "kitti")
    pos = res.trajectory.poses[:, :3, 3]
    rot_id = np.all(np.abs(res.trajectory.poses[:, :3, :3] - np.eye(3)) < 1e-9, axis=(1, 2))
    print(cell.label, f"seed {seed}: tracked {res.tracked}/{res.total} (+{res.frozen} frozen, left out since s20), resets (new maps + resets) {res.resets}, "
          f"max |position| {np.abs(pos).max():.3g} m, identity rotation on {rot_id.sum()} of {len(rot_id)}", flush=True)
