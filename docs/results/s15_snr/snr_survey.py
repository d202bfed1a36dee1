#!/usr/bin/env python
"""Per-cell survey of what ``auto`` does on the generated presets' dark frames and candidate
signal-to-noise measures (s15-snr; docs/notes/s15-snr.md).

For every ``--step``-th left frame of each sequence: auto's decision, the raw grey mean, the exposure
γ, the denoiser σ (after AFE's gain and the curve), and, on the lifted frame (what the denoiser gets):
the texture variance at the guided filter's own scale (3×3 windows on the half-resolution copy, the
filter's var_i) and at ¼ scale, minus the noise's share there (σ²/f² for white noise averaged
over f×f pixels), over σ². Medians and percentiles per cell.

    PYTHONPATH=$PWD python docs/results/s15_snr/snr_survey.py --step 15 DIR [DIR ...]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.enhance.auto import _APPLY, apply_gamma, auto_decide, exposure_gamma  # noqa: E402
from canopy.enhance.common import luma  # noqa: E402
from canopy.enhance.noise import _downsample, estimate_noise  # noqa: E402


def window_var(grey, f, k=3):
    small = _downsample(grey, f).astype(np.float32) if f > 1 else grey.astype(np.float32)
    m = cv2.boxFilter(small, -1, (k, k))
    mm = cv2.boxFilter(small * small, -1, (k, k))
    return np.maximum(mm - m * m, 0)


def frame_stats(img, p):
    decision, st = auto_decide(img, p)
    dark = st["mean"] < p.auto_dark_mean
    out = _APPLY[decision](img, p)
    if not dark:
        return None
    g = exposure_gamma(out, p.auto_dark_target_mean, p.auto_dark_min_gamma)
    lifted = luma(apply_gamma(out, g))
    s = max(estimate_noise(lifted, rows_fraction=p.noise_rows_fraction), p.auto_dark_min_sigma)
    raw_s = estimate_noise(img, rows_fraction=0.5)
    r = dict(raw_mean=float(img.mean()), raw_sigma=raw_s, gamma=g, sigma=s, lifted_mean=float(lifted.mean()))
    for f in (2, 4):
        v = window_var(lifted, f)
        noise = s * s / (f * f) * (8.0 / 9.0)  # white noise: f² pixels averaged, 3×3 sample variance
        for q in (50, 75, 90):
            r[f"snr{f}_p{q}"] = (np.percentile(v, q) - noise) / (s * s)
    # raw-level: the scene's contrast before any gain, over the raw noise
    rv = window_var(luma(img), 4)
    r["raw_snr4_p75"] = (np.percentile(rv, 75) - raw_s ** 2 / 16 * 8 / 9) / max(raw_s, 0.5) ** 2
    return r


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dirs", nargs="+")
    ap.add_argument("--step", type=int, default=15)
    ap.add_argument("--max-frames", type=int, default=350)
    a = ap.parse_args()
    p = load_run_config("synthetic").enhancement
    keys = None
    for d in a.dirs:
        files = sorted((Path(d) / "mav0" / "cam0" / "data").iterdir())[: a.max_frames: a.step]
        rows = [frame_stats(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), p) for f in files]
        dark = [r for r in rows if r]
        name = Path(d).name.replace("-high", "").replace("-rendered", "")
        if not dark:
            print(f"{name:40s} no dark frame of {len(rows)}")
            continue
        keys = keys or list(dark[0])
        med = {k: np.median([r[k] for r in dark]) for k in keys}
        lo = {k: np.min([r[k] for r in dark]) for k in keys}
        hi = {k: np.max([r[k] for r in dark]) for k in keys}
        print(f"{name:40s} dark {len(dark)}/{len(rows)} " + " ".join(
            f"{k}={med[k]:.2f}[{lo[k]:.2f},{hi[k]:.2f}]" for k in keys), flush=True)


if __name__ == "__main__":
    main()
