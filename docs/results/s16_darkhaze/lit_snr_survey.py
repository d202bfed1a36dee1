#!/usr/bin/env python
"""s16-darkhaze: the raw frames of the lit noisy cells (what `auto` decides `none` on): robust noise
sigma and s15's texture SNR (canopy.enhance.snr.texture_snr, 1/4 scale, 90th percentile), every
``--step``-th left frame. Usage:
    PYTHONPATH=$PWD python docs/results/s16_darkhaze/lit_snr_survey.py DATASET DIR [DIR ...] [--step 10]
(DATASET: kitti or a preset name, read as the grid reads it; DIR 'clean' = the dataset's own frames)."""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from canopy.enhance import EnhanceParams  # noqa: E402
from canopy.enhance.auto import auto_decide  # noqa: E402
from canopy.enhance.noise import estimate_noise  # noqa: E402
from canopy.enhance.snr import texture_snr  # noqa: E402
from canopy.sources import open_source  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("dataset")
    ap.add_argument("dirs", nargs="+")
    ap.add_argument("--step", type=int, default=10)
    a = ap.parse_args()
    kind = "kitti" if a.dataset == "kitti" else "euroc"  # the generated presets are EuRoC folders
    for d in a.dirs:
        if d == "clean" and kind == "euroc" and a.dataset != "euroc":
            d = f"/work/cache/synthetic/{a.dataset}-seed0-full"
        src = open_source(kind, None if d == "clean" else d)
        sig, snr, mean, std, dec = [], [], [], [], []
        for i in range(0, len(src), a.step):
            img = src.frame(i).left
            s = estimate_noise(img, rows_fraction=0.5)
            decision, st = auto_decide(img, EnhanceParams())
            sig.append(s)
            snr.append(texture_snr(img, max(s, 1e-3)))
            mean.append(st["mean"])
            std.append(st["std"])
            dec.append(decision)
        q = lambda v: " / ".join(f"{x:.2f}" for x in np.percentile(v, [5, 50, 95]))  # noqa: E731
        print(f"{Path(d).name}: frames {len(sig)}, robust sigma {q(sig)}, texture SNR {q(snr)}, "
              f"grey mean p50 {np.median(mean):.1f}, std p50 {np.median(std):.1f}, decisions {sorted(set(dec))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
