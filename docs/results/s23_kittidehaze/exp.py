"""Guided dehaze experiment: monkeypatch the in-process runner's enhance_pair. usage: exp.py omega radius eps t0 [cells...]"""
import os, sys
from _paths import CELLS, CLEAN, HERE, ORACLE_T, ROOT  # noqa: F401 (also puts the repo on sys.path)

import sys, json, types
import bench_enhance_diagnose as bed
from dehaze_guided import dehaze_guided, dehaze_guided_airlight
omega, radius, eps, t0 = float(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
p = types.SimpleNamespace(guided_omega=omega, guided_radius=radius, guided_eps=eps, guided_t0=t0,
                          auto_downsample=4, n_dark_pixels=200)
orig = bed.enhance_pair
def pair(enhancer, left, right):
    le, re, info = orig(enhancer, left, right)
    a = dehaze_guided_airlight(left, p)
    jl, jr = dehaze_guided(left, p, a), dehaze_guided(right, p, a)
    if DN:
        from canopy.enhance.noise import estimate_noise
        from canopy.enhance.noisy_dark import denoise_frame
        from canopy.enhance.snr import snr_eps_factor
        sigma = estimate_noise(jl, rows_fraction=EP.noise_rows_fraction)
        f = snr_eps_factor(jl, sigma, EP)
        jl, jr = denoise_frame(jl, sigma, EP, f), denoise_frame(jr, sigma, EP, f)
    return jl, jr, info
bed.enhance_pair = pair
import os
DN = os.environ.get("DN") == "1"
from canopy.config import load_run_config
EP = load_run_config("kitti").enhancement
cells = sys.argv[5:] or [f"kitti-all-g1-b0.06-{n}-seed{s}-stereo-sky" for n in ("low", "high") for s in (0, 1, 2)]
res = {}
for c in cells:
    out, rows = bed.run(CELLS + "/" + c, CLEAN, "kitti",
                        {"method": "none"}, {}, None, stereo=False, kind="kitti")
    res[c] = out
    print(c, round(100*out["tracked"],1), round(1e3*out.get("ate", float("nan")),1), flush=True)
