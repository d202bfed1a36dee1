"""What each enhancement gives the tracker, over the degradation grid: correct stereo matches.

The evidence behind ``auto`` (issue 9): not how a picture looks but what
tracking needs, i.e. ORB features that the tracker's own extractor finds in
both images and that its own stereo matcher pairs at the *right* disparity.
For every frame × grid cell (``canopy.degrade.grid_cells``: light × haze β
× noise sensor) × candidate treatment, the pair is degraded, treated (both
images the same way, as the enhancement actor does), run through
``OrbExtractor`` + ``match_stereo`` with the tracking parameters of the
dataset's config, and each stereo match is checked against the reference
disparity: exact depth (``depth0/``) on the generated sequences, SGBM on the
clean pair for KITTI (pixels where it has no valid disparity are not scored).
A match is correct when its disparity is within ``--tol`` px of the
reference. Score = correct matches; precision = correct / matched.

Candidates: the plain methods; ``dn>X`` = noise-aware denoise
(``canopy.enhance.noise``) then X; ``X>dn`` = X then denoise; ``auto`` =
whatever the current ``auto`` decides. All use AFE's adaptive FAST threshold
(Eq. 18–19), as the tracking actor does for ``afe`` and ``auto``, except
``none`` (fixed threshold 20, i.e. ``--enhance none``) and ``auto@20`` (auto's
images with the fixed threshold: the config's ``adaptive_fast: false``).

Noise is seeded per frame and camera, so every frame of every sequence sees
a different noise draw (several seeds).

    CANOPY_CACHE_DIR=/work/cache python benchmarks/bench_enhance_features.py [--frames 3] [--quick]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.degrade import degrade_image, depth_from_stereo, disparity_sgbm, grid_cells, ray_length  # noqa: E402
from canopy.enhance import EnhanceParams, adaptive_fast_threshold, fallback_fast_threshold  # noqa: E402
from canopy.enhance.auto import auto  # noqa: E402
from canopy.enhance.factory import METHOD_FUNCTIONS, make_enhancer, pair_arguments  # noqa: E402
from canopy.enhance.noise import denoise, estimate_noise  # noqa: E402
from canopy.frontend.features import OrbExtractor  # noqa: E402
from canopy.frontend.stereo import match_stereo  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402

PRESETS = ("day-loop", "dusk-loop", "haze-row", "dark-rows")
FIXED_FAST = 20


def candidates(params: EnhanceParams) -> dict:
    """name -> treat(left, right) -> (left', right'); one decision per pair (made on the left)."""
    def plain(m):
        fn = METHOD_FUNCTIONS[m]
        return lambda l, r: (fn(l, params), fn(r, params))

    def pre(m):
        fn = METHOD_FUNCTIONS[m]
        def treat(l, r):
            sigma = estimate_noise(l)
            return tuple(fn(denoise(x, sigma, params.denoise_radius, params.denoise_eps_factor), params)
                         for x in (l, r))
        return treat

    def post(m):
        fn = METHOD_FUNCTIONS[m]
        def treat(l, r):
            le, re = fn(l, params), fn(r, params)
            sigma = estimate_noise(le)
            return tuple(denoise(x, sigma, params.denoise_radius, params.denoise_eps_factor) for x in (le, re))
        return treat

    enhancer = make_enhancer(params)  # exactly as the enhancement actor treats a pair

    def auto_pair(l, r):
        le, info = enhancer(l)
        return le, enhancer(r, **pair_arguments(info))[0]

    out = {m: plain(m) for m in ("none", "clahe", "afe", "agri", "dehaze")}
    for m in ("none", "clahe", "afe", "agri"):
        out[f"dn>{m}"] = pre(m)
    for m in ("clahe", "afe", "agri"):
        out[f"{m}>dn"] = post(m)
    out["auto"] = auto_pair
    out["auto@20"] = auto_pair  # the same images, scored with the fixed FAST threshold
    return out


def load_frames(n_per_seq: int, cache: Path, quick: bool):
    """[(sequence, frame index, left, right, calib, reference disparity, n_features)]."""
    out = []
    presets = PRESETS[:2] + PRESETS[3:] if quick else PRESETS
    for preset in presets:
        root = cache / "synthetic" / f"{preset}-seed0-full"
        if not root.is_dir():
            print(f"  (skipping {preset}: {root} not generated)")
            continue
        src = open_source("euroc", root)
        nf = load_run_config("synthetic").tracking.n_features
        for i in np.linspace(10, len(src) - 10, n_per_seq).astype(int):
            fr = src.frame(int(i))
            depth_png = root / "mav0" / "depth0" / "data" / src.left_paths[i].name
            z = cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED).astype(np.float64) / 1000.0
            disp = np.where(z > 0, src.calibration.bf / np.maximum(z, 1e-6), -1.0)
            out.append((preset, int(i), fr.left, fr.right, src.calibration, disp, nf))
    for kind in ("kitti", "euroc"):
        src = open_source(kind, BUNDLED_DATA[kind])
        nf = load_run_config(kind).tracking.n_features
        for i in np.linspace(0, len(src) - 1, max(1, n_per_seq - 1)).astype(int):
            fr = src.frame(int(i))
            disp = disparity_sgbm(fr.left, fr.right).astype(np.float64)
            disp[disp <= 0] = -1.0
            out.append((kind, int(i), fr.left, fr.right, src.calibration, disp, nf))
    return out


def haze_rays(left, right, calib, max_depth):
    """Ray-length maps of both views from SGBM on the clean pair (what tools/degrade_sequence.py does)."""
    return [ray_length(depth_from_stereo(left, right, calib, max_depth=max_depth, view=v), calib)
            for v in ("left", "right")]


def score_pair(left, right, calib, ref_disp, extractors, tracking, adaptive: bool, tol: float, omega: float):
    ext_l, ext_r = extractors
    if adaptive:
        thr, low = adaptive_fast_threshold(left, omega), fallback_fast_threshold(left, omega)
        fl = ext_l.extract(left, thr, low, 200)
        fr = ext_r.extract(right, thr, low, 200)
    else:
        fl, fr = ext_l.extract(left, FIXED_FAST), ext_r.extract(right, FIXED_FAST)
    st = match_stereo(fl, fr, left, right, calib, tracking)
    ok = st.valid
    if not ok.any():
        return {"kp": len(fl), "matched": 0, "correct": 0}
    uv = fl.uv[ok]
    d_est = uv[:, 0] - st.u_right[ok]
    h, w = ref_disp.shape
    col = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
    d_ref = ref_disp[row, col]
    scored = d_ref > 0
    correct = scored & (np.abs(d_est - d_ref) <= tol)
    return {"kp": len(fl), "matched": int(ok.sum()), "scored": int(scored.sum()), "correct": int(correct.sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3, help="frames per sequence (KITTI/EuRoC: one fewer)")
    ap.add_argument("--tol", type=float, default=1.0, help="disparity error (px) of a correct match")
    ap.add_argument("--quick", action="store_true", help="3 generated presets, noise level 'high' only")
    ap.add_argument("--only", default="", help="comma-separated candidate names to run (default: all)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_enhance_features.json"))
    args = ap.parse_args(argv)

    cache = Path(os.environ.get("CANOPY_CACHE_DIR", ROOT / "cache"))
    params = EnhanceParams(method="auto")
    cands = candidates(params)
    if args.only:
        cands = {k: v for k, v in cands.items() if k in args.only.split(",")}
    frames = load_frames(args.frames, cache, args.quick)
    cells = grid_cells(noise_levels=("high",) if args.quick else ("low", "high"))
    print(f"{len(frames)} frames x {len(cells)} cells x {len(cands)} candidates")
    rows = []
    t_start = time.time()
    for fi, (seq, idx, left, right, calib, ref, nf) in enumerate(frames):
        tracking = load_run_config("kitti" if seq == "kitti" else "euroc").tracking
        extractors = (OrbExtractor(tracking), OrbExtractor(tracking))
        rays = haze_rays(left, right, calib, cells[0].max_depth)
        for cell in cells:
            seed = [cell.seed, fi, idx]
            dl = degrade_image(left, cell, rays[0], rng=np.random.default_rng(seed + [0]))
            dr = degrade_image(right, cell, rays[1], rng=np.random.default_rng(seed + [1]))
            for name, treat in cands.items():
                tl, tr = treat(dl, dr)
                s = score_pair(tl, tr, calib, ref, extractors, tracking,
                               name != "none" and not name.endswith("@20"), args.tol,
                               params.fast_omega)
                row = {"sequence": seq, "frame": idx, "cell": cell.label, "candidate": name, **s}
                if name.startswith("auto"):
                    row["decision"] = auto(dl, params)[1]
                    row["noise_sigma_in"] = estimate_noise(dl)
                rows.append(row)
        print(f"  {seq}:{idx} done ({time.time() - t_start:.0f} s)", flush=True)

    # summary: per cell, mean correct matches per candidate over frames
    names = list(cands)
    cell_names = [c.label for c in cells]
    table = {c: {n: float(np.mean([r["correct"] for r in rows if r["cell"] == c and r["candidate"] == n]))
                 for n in names} for c in cell_names}
    print(f"\n{'cell':<18}" + "".join(f"{n[:9]:>10}" for n in names) + "   best")
    for c in cell_names:
        best = max(names, key=lambda n: table[c][n])
        print(f"{c:<18}" + "".join(f"{table[c][n]:>10.0f}" for n in names) + f"   {best}")
    # per candidate: fraction of the best candidate's score, averaged over (frame, cell)
    rel = {n: [] for n in names}
    keys = sorted({(r["sequence"], r["frame"], r["cell"]) for r in rows})
    by = {(r["sequence"], r["frame"], r["cell"], r["candidate"]): r["correct"] for r in rows}
    for k in keys:
        best = max(by[k + (n,)] for n in names)
        for n in names:
            rel[n].append(by[k + (n,)] / best if best > 0 else 1.0)
    print("\nmean fraction of the best candidate's correct matches (1 = always best):")
    for n in names:
        print(f"  {n:<10} {np.mean(rel[n]):.3f}   worst {np.min(rel[n]):.3f}")
    result = {"benchmark": "bench_enhance_features", "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "tol_px": args.tol, "frames": [(f[0], f[1]) for f in frames], "cells": cell_names,
              "mean_correct": table, "fraction_of_best": {n: float(np.mean(v)) for n, v in rel.items()},
              "rows": rows}
    print(f"\nwrote {write_json(args.out, result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
