#!/usr/bin/env python
"""Tables of docs/notes/s12-drift.md §1 from ``depth_bias.py``'s npz: per segment, the contour
test's groups (flagged only for "no StereoBM match near it", flagged for a disparity step,
unflagged) against the exact depth, and the surface points' disparity error per image band and
pyramid level.

    python docs/results/s12_drift/depth_groups.py /tmp/s12drift/depth_bias.npz
"""
import sys

import numpy as np

r = np.load(sys.argv[1])["rows"]
f, u, v, o, z, zt, zlo, zhi, on, ons = r.T
rel = z / zt - 1.0                                     # sky at the pixel: zt = inf, rel = -1
fb = 435.0 * 0.11                                      # the generated rig's fx * baseline
dd = fb / z - fb / zt                                  # disparity error, px
surface = np.isfinite(zhi) & (zhi < 1.05 * zlo)        # exact depth within 5 % over 5x5 px
SEG = ((0, 303, "row 1"), (303, 506, "turn 1"), (506, 810, "row 2"), (810, 1014, "turn 2"))
print("| segment | group | share of stereo pts | depth > 10 % off | sky at the pixel | surface | upper half |")
print("|---|---|---|---|---|---|---|")
for a, b, n in SEG:
    s = (f >= a) & (f < b)
    for g, m in (("unmatched near only", s & (on > 0) & (ons == 0)), ("disparity step", s & (ons > 0)),
                 ("unflagged", s & (on == 0))):
        bad = m & (np.abs(rel) > 0.1)
        print(f"| {n} | {g} | {m.sum() / s.sum():.1%} | {bad.sum() / m.sum():.1%} | "
              f"{np.mean(~np.isfinite(zt[m])):.1%} | {surface[m].mean():.1%} | {np.mean(v[m] < 240):.0%} |")
print("\nsurface points, median disparity error (px) per image band (rows of 96 px, top first)")
for a, b, n in SEG:
    s = (f >= a) & (f < b) & surface
    print(n, " ".join(f"{np.median(dd[s & (v >= v0) & (v < v0 + 96)]):+.3f}" for v0 in range(0, 480, 96)))
print("\nsurface points below the image centre, median disparity error (px) per pyramid level 0..7")
turn = ~((f < 303) | ((f >= 506) & (f < 810)))
for n, m0 in (("rows", ~turn), ("turns", turn)):
    m = m0 & surface & (v > 260)
    print(n, " ".join(f"{np.median(dd[m & (o == k)]):+.3f}" for k in range(8)))
