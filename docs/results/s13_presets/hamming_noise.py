#!/usr/bin/env python
"""How far the grid's sensor noise alone moves ORB descriptors: the same keypoints (cv2.ORB on the
clean frame, 1000 corners) described in two independent noise draws of the same frame (the cached
seed-0 and seed-1 cells), Hamming distance per keypoint. A true local-map match on a noisy sequence
compares two such noisy descriptors (plus the motion's change), so the share above the tracker's
``map_max_hamming`` is the share of true matches the noise alone rejects.

    PYTHONPATH=$PWD python docs/results/s13_presets/hamming_noise.py CLEAN_DIR CELL_SEED0 CELL_SEED1 [N STEP]
"""
import sys
from pathlib import Path

import cv2
import numpy as np


def frames(d):
    return sorted((Path(d) / "mav0" / "cam0" / "data").iterdir())


def main():
    clean, a, b = sys.argv[1:4]
    n = int(sys.argv[4]) if len(sys.argv) > 4 else 150
    step = int(sys.argv[5]) if len(sys.argv) > 5 else 10
    orb = cv2.ORB_create(1000, 1.2, 8)
    fc, fa, fb = frames(clean), frames(a), frames(b)
    dist_cc, dist_ab, dist_det, repeat = [], [], [], []
    for i in range(0, min(n, len(fa), len(fb)), step):
        ic, ia, ib = (cv2.imread(str(f[i]), 0) for f in (fc, fa, fb))
        kp = orb.detect(ic, None)
        kc, dc = orb.compute(ic, kp)
        ka, da = orb.compute(ia, kc)
        kb, db = orb.compute(ib, kc)
        # keep keypoints described in all three (compute may drop border ones; it keeps order)
        if not (len(ka) == len(kb) == len(kc)):
            continue
        bits = lambda x, y: np.unpackbits(np.bitwise_xor(x, y), axis=1).sum(1)  # noqa: E731
        dist_ab.append(bits(da, db))
        dist_cc.append(bits(da, dc))
        # each draw detected on its own (what two frames of a noisy sequence give): the keypoint of
        # draw 1 nearest to each of draw 0's (same octave, within 1.5 px) and their descriptors
        for img_a, img_b, out in ((ia, ib, dist_det), (ic, ic, None)):
            if out is None:
                continue
            ka2, da2 = orb.detectAndCompute(img_a, None)
            kb2, db2 = orb.detectAndCompute(img_b, None)
            pa = np.array([k.pt for k in ka2]); pb = np.array([k.pt for k in kb2])
            oa = np.array([k.octave for k in ka2]); ob = np.array([k.octave for k in kb2])
            d2 = ((pa[:, None, :] - pb[None, :, :]) ** 2).sum(-1)
            d2[oa[:, None] != ob[None, :]] = np.inf
            j = d2.argmin(1)
            ok = d2[np.arange(len(pa)), j] <= 1.5 ** 2
            out.append(bits(da2[ok], db2[j[ok]]))
            repeat.append(ok.mean())
    ab, ac, det = np.concatenate(dist_ab), np.concatenate(dist_cc), np.concatenate(dist_det)
    print(f"{Path(a).name}: keypoints of draw 0 found again in draw 1 (same octave, 1.5 px): {np.mean(repeat):.1%}")
    for name, d in (("same keypoints, draw 0 vs draw 1", ab), ("same keypoints, draw 0 vs clean", ac),
                    ("detected per draw, draw 0 vs draw 1", det)):
        print(f"{Path(a).name}: {name}: n {len(d)}, median {np.median(d):.0f}, p90 {np.percentile(d, 90):.0f}, "
              f"> 50 {np.mean(d > 50):.1%}, > 75 {np.mean(d > 75):.1%}, > 100 {np.mean(d > 100):.1%}")


if __name__ == "__main__":
    main()
