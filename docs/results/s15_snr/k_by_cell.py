#!/usr/bin/env python
"""The SNR rule's ε factor on every frame of degraded preset cells (s15-snr), as the enhancement actor
computes it (``PairEnhancer`` with configs/synthetic.yaml's enhancement section, or ``--off`` for main's).
A cell whose every frame gets the factor 2 is treated exactly as on main (same pixels), so its SLAM run
is main's row to the digit.

    PYTHONPATH=$PWD python docs/results/s15_snr/k_by_cell.py /work/cache/degraded/<cell> [...]
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.enhance.pair import PairEnhancer  # noqa: E402
from canopy.enhance.snr import texture_snr  # noqa: E402
from canopy.enhance.auto import _APPLY, apply_gamma, auto_decide, exposure_gamma  # noqa: E402


def main():
    p = load_run_config("synthetic").enhancement
    for d in sys.argv[1:]:
        name = Path(d).name
        mf = 150 if name.startswith("dark-rows") else 300 if name.startswith("day-loop") else 346
        cam = Path(d) / "mav0"
        left = sorted((cam / "cam0" / "data").iterdir())[:mf]
        right = sorted((cam / "cam1" / "data").iterdir())[:mf]
        pe = PairEnhancer(p)
        ks, snrs, dec = [], [], {}
        for lf, rf in zip(left, right):
            li, ri = cv2.imread(str(lf), cv2.IMREAD_GRAYSCALE), cv2.imread(str(rf), cv2.IMREAD_GRAYSCALE)
            _, _, info = pe(li, ri)
            dec[info["method"]] = dec.get(info["method"], 0) + 1
            ks.append(info["eps_factor"])
            if info["noise_sigma"] > 0:
                d0, _ = auto_decide(li, p)
                base = _APPLY[d0](li, p)
                snrs.append(texture_snr(apply_gamma(base, info["gamma"]), info["noise_sigma"],
                                        p.denoise_snr_downsample, p.denoise_snr_quantile))
        ks = np.array(ks)
        dn = ks[ks > 0]
        s = np.array(snrs) if snrs else np.array([np.nan])
        print(f"{name:48s} {dec}  denoised {len(dn)}/{len(ks)}  factor 2: {int(np.sum(dn == 2.0))}, "
              f"1.25: {int(np.sum(dn == 1.25))}, between: {int(np.sum((dn > 1.25) & (dn < 2.0)))}"
              f"  SNR p5/50/95 {np.nanpercentile(s, 5):.2f}/{np.nanpercentile(s, 50):.2f}/{np.nanpercentile(s, 95):.2f}",
              flush=True)


if __name__ == "__main__":
    main()
