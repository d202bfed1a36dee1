"""What the dark channel prior dehazing does to the sensor noise on the grid's hazy cells.

Per cell, frames 0, 10, ..., of the left camera: auto's statistics (mean, std, dark channel of the
¼-scale copy), the decision, the robust noise σ (canopy.enhance.noise.estimate_noise) of the raw
frame and of the dehazed frame (AGRI Eq. 2–4 on the image itself), and the median gain 1/t of
Eq. 4 over the frame (t from Eq. 3, clamped at t0). Medians over the frames are printed.

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s11_haze/dehaze_noise.py
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.enhance.auto import auto_decide  # noqa: E402
from canopy.enhance.dehaze import atmospheric_light, dark_channel, dehaze_dark_channel  # noqa: E402
from canopy.enhance.noise import estimate_noise  # noqa: E402
from canopy.enhance.params import EnhanceParams  # noqa: E402
from canopy.sources import open_source  # noqa: E402

CELLS = [("kitti", "kitti-all-g1-b0-high-seed0"), ("kitti", "kitti-all-g1-b0.03-high-seed0"),
         ("kitti", "kitti-all-g1-b0.06-high-seed0"), ("kitti", "kitti-all-g1-b0.06-low-seed0"),
         ("kitti", "kitti-all-g0.15-b0.06-high-seed0"),
         ("euroc", "day-loop-300-g1-b0.06-high-seed0-rendered"), ("euroc", "haze-row-346-g1-b0.06-high-seed0-rendered"),
         ("euroc", "dark-rows-150-g1-b0.06-high-seed0-rendered")]


def main():
    p = EnhanceParams()
    print(f"{'cell':<44} {'mean':>5} {'std':>5} {'dark':>5} {'decision':<8} {'σ raw':>6} {'σ dehazed':>9} {'1/t med':>7}")
    for kind, cell in CELLS:
        src = open_source(kind, Path("/work/cache/degraded") / cell)
        vals, decs = [], {}
        for i in range(0, len(src), 10):
            img = src.frame(i).left
            dec, st = auto_decide(img, p)
            decs[dec] = decs.get(dec, 0) + 1
            dk = dark_channel(img, p.block)
            a = atmospheric_light(img, dk, p.n_dark_pixels)[0]
            t = np.clip(1.0 - p.omega * dk / a, p.t0, 1.0)
            vals.append((st["mean"], st["std"], st["dark"], estimate_noise(img),
                         estimate_noise(dehaze_dark_channel(img, p)), float(np.median(1.0 / t))))
        m = np.median(np.array(vals), axis=0)
        print(f"{cell:<44} {m[0]:5.0f} {m[1]:5.1f} {m[2]:5.0f} {max(decs, key=decs.get):<8} {m[3]:6.2f} {m[4]:9.2f} {m[5]:7.2f}")


if __name__ == "__main__":
    main()
