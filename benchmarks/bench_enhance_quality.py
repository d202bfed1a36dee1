"""What each enhancement method does to images and to features, on real data.

1. Reference quality (PSNR, SSIM from scikit-image) against the clean image:
   O-HAZE ``haze_pairs`` (hazy vs clear, dehazed vs clear; colour, full size)
   and the LOL pair 778 (low vs normal, enhanced vs normal).
2. ORB keypoints on the 29 LIME/DICM low-light photos (grey), per method,
   with OpenCV's ORB (1000 features) at the fixed FAST threshold (20) and at
   AFE's adaptive one (Eq. 18, Eq. 19 retry below ``min_keypoints``).
3. Stereo on sequences: the first ``--frames`` frames of the bundled EuRoC
   and KITTI snippets, as recorded, darkened (gain 0.15) and hazy (KITTI
   β = 0.05 /m; EuRoC, indoors at 1–5 m, β = 0.3 /m), made with
   ``tools/degrade_sequence.py`` and read back through ``open_source``.
   Enhancement exactly as the enhancement actor applies it (the left image
   decides, the right one gets the same method); features and stereo matches
   from the tracking front end (``OrbExtractor``, ``match_stereo``, default
   ``TrackingParams``) with the fixed FAST threshold and with the adaptive one
   as the tracking actor computes it (Eq. 18 on the enhanced left image).
   Spread: cells of an 8×8 grid holding at least one stereo match.

    python benchmarks/bench_enhance_quality.py [--frames 10] [--out results/bench_enhance_quality.json]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.degrade import DegradeParams  # noqa: E402
from canopy.enhance import EnhanceParams, adaptive_fast_threshold, detect_orb_adaptive, make_enhancer  # noqa: E402
from canopy.frontend import OrbExtractor, TrackingParams, match_stereo  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from canopy.report import write_json  # noqa: E402
from tools.degrade_sequence import degrade_sequence  # noqa: E402

SHARED_DATA = ROOT.parent / "shared" / "data"
METHODS = ("none", "he", "clahe", "afe", "agri", "auto", "dehaze")  # dehaze: plain dark channel prior
ORB_FEATURES = 1000
GRID = 8
CONDITIONS = {
    "kitti": {"dark": DegradeParams(mode="dark", gain=0.15),
              "haze": DegradeParams(mode="haze", beta=0.05, max_depth=200.0)},
    "euroc": {"dark": DegradeParams(mode="dark", gain=0.15),
              "haze": DegradeParams(mode="haze", beta=0.3, max_depth=20.0)},
}


def enhancers() -> dict:
    """One enhancer per method; ``dehaze`` goes through the factory's forced-method path."""
    out = {m: make_enhancer(EnhanceParams(method=m)) for m in METHODS if m != "dehaze"}
    base = make_enhancer(EnhanceParams(method="none"))
    out["dehaze"] = lambda img, method=None: base(img, method=method or "dehaze")
    return out


def read(path: Path, flags=cv2.IMREAD_COLOR) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        raise SystemExit(f"bench_enhance_quality: cannot read {path}")
    return img


def quality(img: np.ndarray, ref: np.ndarray) -> dict:
    return {"psnr": float(peak_signal_noise_ratio(ref, img, data_range=255)),
            "ssim": float(structural_similarity(ref, img, channel_axis=2 if img.ndim == 3 else None,
                                                data_range=255))}


def reference_quality(enh: dict) -> list[dict]:
    pairs = []
    for hazy in sorted((SHARED_DATA / "haze_pairs" / "hazy").glob("*_hazy.jpg")):
        clear = SHARED_DATA / "haze_pairs" / "clear" / hazy.name.replace("_hazy", "_GT")
        pairs.append(("haze", hazy.stem.replace("_outdoor_hazy", ""), read(hazy), read(clear)))
    lol = SHARED_DATA / "lol_pair_778" / "img"
    pairs.append(("lowlight", "LOL 778", read(lol / "778_input.png"), read(lol / "778.png")))
    rows = []
    for kind, name, degraded, clean in pairs:
        rows.append({"set": kind, "image": name, "method": "(input)", "decision": "-", **quality(degraded, clean)})
        for m in METHODS:
            out, info = enh[m](degraded)
            rows.append({"set": kind, "image": name, "method": m, "decision": info["method"], **quality(out, clean)})
    return rows


def orb_counts(enh: dict) -> list[dict]:
    root = SHARED_DATA / "lowlight_lime_dicm" / "Zero-DCE_code" / "data" / "test_data"
    photos = sorted(root.glob("LIME/*.bmp")) + sorted(root.glob("DICM/*.jpg"))
    if not photos:
        raise SystemExit(f"bench_enhance_quality: no LIME/DICM photos under {root}")
    params = EnhanceParams()
    orb = cv2.ORB_create(ORB_FEATURES)
    fixed_threshold = orb.getFastThreshold()
    images = [read(p, cv2.IMREAD_GRAYSCALE) for p in photos]
    rows = []
    for m in METHODS:
        fixed, adaptive, thetas, means, decisions = [], [], [], [], {}
        for img in images:
            out, info = enh[m](img)
            decisions[info["method"]] = decisions.get(info["method"], 0) + 1
            orb.setFastThreshold(fixed_threshold)
            fixed.append(len(orb.detect(out, None)))
            kps, _desc, theta = detect_orb_adaptive(out, orb, params)
            adaptive.append(len(kps))
            thetas.append(theta)
            means.append(float(out.mean()))
        rows.append({"method": m, "photos": len(images), "decisions": decisions, "mean_grey": float(np.mean(means)),
                     "kp_fixed_mean": float(np.mean(fixed)), "kp_fixed_min": int(np.min(fixed)),
                     "kp_adaptive_mean": float(np.mean(adaptive)), "kp_adaptive_min": int(np.min(adaptive)),
                     "theta_mean": float(np.mean(thetas)), "fixed_threshold": int(fixed_threshold)})
    return rows


def grid_cells(uv: np.ndarray, width: int, height: int) -> int:
    if len(uv) == 0:
        return 0
    cx = np.clip((uv[:, 0] * GRID / width).astype(int), 0, GRID - 1)
    cy = np.clip((uv[:, 1] * GRID / height).astype(int), 0, GRID - 1)
    return int(len(np.unique(cy * GRID + cx)))


def stereo_features(enh: dict, frames: int, workdir: Path) -> list[dict]:
    tparams = TrackingParams()
    extractor = OrbExtractor(tparams)
    rows = []
    for dataset, conditions in CONDITIONS.items():
        sources = {"clear": open_source(dataset, max_frames=frames)}
        for cond, dparams in conditions.items():
            out = degrade_sequence(dataset, workdir / f"{dataset}_{cond}", dparams, max_frames=frames, force=True)
            sources[cond] = open_source(dataset, out)
        calib = sources["clear"].calibration
        for cond, src in sources.items():
            pairs = [src.frame(i) for i in range(len(src))]
            for m in METHODS:
                enhanced, decisions = [], {}
                for f in pairs:
                    left, info = enh[m](f.left)
                    right, _ = enh[m](f.right, method=info["method"])  # as the enhancement actor does
                    enhanced.append((left, right))
                    decisions[info["method"]] = decisions.get(info["method"], 0) + 1
                for fast in ("fixed", "adaptive"):
                    kps, matches, cells = [], [], []
                    for left, right in enhanced:
                        theta = adaptive_fast_threshold(left) if fast == "adaptive" else None
                        fl, fr = extractor.extract(left, theta), extractor.extract(right, theta)
                        st = match_stereo(fl, fr, left, right, calib, tparams)
                        kps.append(len(fl))
                        matches.append(int(st.valid.sum()))
                        cells.append(grid_cells(fl.uv[st.valid], calib.width, calib.height))
                    rows.append({"dataset": dataset, "condition": cond, "method": m, "fast": fast,
                                 "frames": len(enhanced), "decisions": decisions,
                                 "mean_grey": float(np.mean([l.mean() for l, _ in enhanced])),
                                 "kp_mean": float(np.mean(kps)), "matches_mean": float(np.mean(matches)),
                                 "matches_min": int(np.min(matches)), "cells_mean": float(np.mean(cells)),
                                 "cells_min": int(np.min(cells))})
    return rows


def _decisions(d: dict) -> str:
    return ",".join(f"{k}:{v}" for k, v in sorted(d.items()))


def print_tables(ref_rows, orb_rows, stereo_rows) -> None:
    print("\n== Reference quality (PSNR dB / SSIM vs the clean image) ==")
    print(f"{'set':<9} {'image':<8} {'method':<8} {'auto->':<7} {'PSNR':>7} {'SSIM':>7}")
    for r in ref_rows:
        print(f"{r['set']:<9} {r['image']:<8} {r['method']:<8} {r['decision'] if r['method'] == 'auto' else '':<7} "
              f"{r['psnr']:>7.2f} {r['ssim']:>7.4f}")
    print(f"\n== ORB keypoints (ORB_create({ORB_FEATURES})) on {orb_rows[0]['photos']} LIME/DICM photos, grey ==")
    print(f"{'method':<8} {'grey':>6} {'kp fixed':>9} {'min':>5} {'kp adapt':>9} {'min':>5} {'θ mean':>7}  decisions")
    for r in orb_rows:
        print(f"{r['method']:<8} {r['mean_grey']:>6.1f} {r['kp_fixed_mean']:>9.1f} {r['kp_fixed_min']:>5d} "
              f"{r['kp_adaptive_mean']:>9.1f} {r['kp_adaptive_min']:>5d} {r['theta_mean']:>7.1f}  "
              f"{_decisions(r['decisions'])}")
    print("\n== Stereo on sequences (means per frame; cells: of 8x8 with >= 1 stereo match) ==")
    print(f"{'data':<6} {'cond':<6} {'method':<7} {'grey':>6} | {'fixed FAST: kp':>14} {'match':>6} {'cells':>6} | "
          f"{'adaptive: kp':>12} {'match':>6} {'cells':>6}  decisions")
    by_key = {(r["dataset"], r["condition"], r["method"], r["fast"]): r for r in stereo_rows}
    for (d, c, m, fast), r in by_key.items():
        if fast != "fixed":
            continue
        a = by_key[(d, c, m, "adaptive")]
        print(f"{d:<6} {c:<6} {m:<7} {r['mean_grey']:>6.1f} | {r['kp_mean']:>14.0f} {r['matches_mean']:>6.0f} "
              f"{r['cells_mean']:>6.1f} | {a['kp_mean']:>12.0f} {a['matches_mean']:>6.0f} {a['cells_mean']:>6.1f}  "
              f"{_decisions(r['decisions'])}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=10, help="frames of each bundled sequence")
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_enhance_quality.json"))
    args = ap.parse_args(argv)
    if not SHARED_DATA.is_dir():
        raise SystemExit(f"bench_enhance_quality: shared data folder not found: {SHARED_DATA}")

    enh = enhancers()
    t0 = time.perf_counter()
    ref_rows = reference_quality(enh)
    t1 = time.perf_counter()
    orb_rows = orb_counts(enh)
    t2 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="canopy_bench_quality_") as tmp:
        stereo_rows = stereo_features(enh, args.frames, Path(tmp))
    t3 = time.perf_counter()
    print_tables(ref_rows, orb_rows, stereo_rows)

    result = {
        "benchmark": "bench_enhance_quality",
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
                    "opencv": cv2.__version__, "platform": platform.platform()},
        "frames_per_sequence": args.frames,
        "degradations": {d: {c: {k: getattr(p, k) for k in ("mode", "gain", "full_well", "read_noise", "beta",
                                                             "airlight", "max_depth", "seed")}
                             for c, p in conds.items()} for d, conds in CONDITIONS.items()},
        "wall_s": {"reference_quality": t1 - t0, "orb_photos": t2 - t1, "stereo_sequences": t3 - t2},
        "reference_quality": ref_rows,
        "orb_lime_dicm": orb_rows,
        "stereo_sequences": stereo_rows,
    }
    print(f"\nwrote {write_json(args.out, result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
