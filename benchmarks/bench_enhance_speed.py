"""Speed of each enhancement method on real grey frames (ms per frame, median of N runs).

Frames: EuRoC V1_01 cam0 (752×480) and KITTI 06 image_l (1226×370), both grey,
from ``data/`` or ``../shared/data``. ``auto`` is timed on the frame as
recorded (well lit: it decides ``none`` and only pays for its statistics and
the noise estimate), on a darkened copy (radiance ×0.25) and on a dark noisy
copy (``canopy.degrade``: 6 % light, the grid's "high" noise sensor; it
decides ``afe>dn``). The noise estimator and the denoiser are timed alone,
and ``auto pair`` is a whole stereo pair as the enhancement actor treats it
(left decides, right follows with the left's σ): the issue 9 budget is 4 ms
per pair on 2 cores.

    python benchmarks/bench_enhance_speed.py [--runs 200] [--out results/bench_enhance_speed.json]

The pair table (``PairEnhancer``, as the enhancement actor runs it) gives the wall time with the
two images on two threads and one after the other, and the CPU time of all threads, per method
on dark noisy pairs; the machine's load average is recorded with the results.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.degrade import NOISE_LEVELS, DegradeParams, degrade_image  # noqa: E402
from canopy.enhance import EnhanceParams, auto, dehaze_dark_channel, denoise, estimate_noise, make_enhancer  # noqa: E402
from canopy.enhance.factory import METHOD_FUNCTIONS, pair_arguments  # noqa: E402
from canopy.report import write_json  # noqa: E402

FRAMES = {
    "euroc_752x480": "euroc_v101_micro/mav0/cam0/data/1403715273262142976.png",
    "kitti_1226x370": "kitti06_snippet/image_l/000000.png",
}
RIGHT = {"euroc_752x480": "euroc_v101_micro/mav0/cam1/data/1403715273262142976.png",
         "kitti_1226x370": "kitti06_snippet/image_r/000000.png"}
NOISY = DegradeParams(mode="dark", gain=0.06, full_well=NOISE_LEVELS["high"][0], read_noise=NOISE_LEVELS["high"][1])
DARKEN = 0.25
# dark cells of the degradation grid (canopy.degrade.grid_cells) for the pair table
DARK_CELLS = {"6 % light, high noise": NOISY,
              "15 % light, low noise": DegradeParams(mode="dark", gain=0.15, full_well=NOISE_LEVELS["low"][0],
                                                      read_noise=NOISE_LEVELS["low"][1])}
PAIR_METHODS = ("auto", "afe", "agri", "clahe", "he")
WARMUP = 10


def find_frame(rel: str) -> Path:
    for base in (ROOT / "data", ROOT.parent / "shared" / "data"):
        if (base / rel).is_file():
            return base / rel
    raise SystemExit(f"bench_enhance_speed: frame not found: {rel} (looked in data/ and ../shared/data)")


def time_ms(fn, image, runs: int) -> dict:
    for _ in range(WARMUP):
        fn(image)
    samples = []
    for _ in range(runs):
        start = time.perf_counter()
        fn(image)
        samples.append((time.perf_counter() - start) * 1e3)
    samples.sort()
    return {"median_ms": statistics.median(samples), "p90_ms": samples[int(0.9 * (len(samples) - 1))],
            "min_ms": samples[0]}


def time_pair(fn, pair, runs: int) -> dict:
    """Wall time (min / median ms) and CPU time of every thread of the process (median ms) per call."""
    for _ in range(WARMUP):
        fn(pair)
    wall, cpu = [], []
    for _ in range(runs):
        w0, c0 = time.perf_counter(), time.process_time()
        fn(pair)
        wall.append((time.perf_counter() - w0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    wall.sort()
    return {"wall_min_ms": wall[0], "wall_median_ms": statistics.median(wall), "cpu_min_ms": min(cpu),
            "cpu_median_ms": statistics.median(cpu)}


def pair_table(runs: int) -> list[dict]:
    """A whole stereo pair as the enhancement actor treats it (``PairEnhancer``: the two images on two
    threads; ``serial``: one after the other), per method, on dark noisy pairs (issue 9 budget: 4 ms)."""
    from canopy.enhance.pair import PairEnhancer

    rows = []
    for frame_name, rel in FRAMES.items():
        left = cv2.imread(str(find_frame(rel)), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(find_frame(RIGHT[frame_name])), cv2.IMREAD_GRAYSCALE)
        pairs = {"as recorded": (left, right)}
        for label, cell in DARK_CELLS.items():
            pairs[label] = (degrade_image(left, cell, rng=1), degrade_image(right, cell, rng=2))
        for method in PAIR_METHODS:
            for label, pair in pairs.items():
                if label == "as recorded" and method != "auto":
                    continue
                params = EnhanceParams(method=method)
                for threads in ("2 threads", "serial"):
                    enh = PairEnhancer(params, parallel=threads == "2 threads")
                    decision = enh(*pair)[2]["method"]
                    rows.append({"frame": frame_name, "method": method, "input": label, "decision": decision,
                                 "threads": threads, **time_pair(lambda p: enh(*p), pair, runs)})
                    enh.close()
    print(f"{'frame':<16} {'method':<6} {'input':<22} {'decision':<8} {'threads':<10} {'wall min':>9} "
          f"{'wall med':>9} {'cpu min':>8} {'cpu med':>8}")
    for r in rows:
        print(f"{r['frame']:<16} {r['method']:<6} {r['input']:<22} {r['decision']:<8} {r['threads']:<10} "
              f"{r['wall_min_ms']:>9.2f} {r['wall_median_ms']:>9.2f} {r['cpu_min_ms']:>8.2f} "
              f"{r['cpu_median_ms']:>8.2f}", flush=True)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_enhance_speed.json"))
    ap.add_argument("--pair-only", action="store_true", help="only the pair table (the issue 9 budget)")
    args = ap.parse_args(argv)

    params = EnhanceParams()
    cases = {name: (lambda f: (lambda img: f(img, params)))(fn) for name, fn in METHOD_FUNCTIONS.items()}
    cases["dehaze"] = lambda img: dehaze_dark_channel(img, params)
    cases["auto"] = lambda img: auto(img, params)
    cases["noise estimate"] = estimate_noise
    cases["denoise"] = lambda img: denoise(img, 8.0, params.denoise_radius, params.denoise_eps_factor)
    enhancer = make_enhancer(EnhanceParams(method="auto"))

    def auto_pair(pair):
        left, info = enhancer(pair[0])
        return enhancer(pair[1], **pair_arguments(info))

    rows = []
    load_before = os.getloadavg()
    pair_rows = pair_table(args.runs)
    for frame_name, rel in ({} if args.pair_only else FRAMES).items():
        image = cv2.imread(str(find_frame(rel)), cv2.IMREAD_GRAYSCALE)
        dark = cv2.convertScaleAbs(image, alpha=DARKEN)
        for method, fn in cases.items():
            extra = {"decision": auto(image, params)[1]} if method == "auto" else {}
            rows.append({"frame": frame_name, "shape": list(image.shape), "method": method,
                         "input": "as recorded", **extra, **time_ms(fn, image, args.runs)})
        rows.append({"frame": frame_name, "shape": list(image.shape), "method": "auto",
                     "input": f"darkened x{DARKEN}", "decision": auto(dark, params)[1],
                     **time_ms(cases["auto"], dark, args.runs)})
        right = cv2.imread(str(find_frame(RIGHT[frame_name])), cv2.IMREAD_GRAYSCALE)
        noisy = (degrade_image(image, NOISY, rng=1), degrade_image(right, NOISY, rng=2))
        rows.append({"frame": frame_name, "shape": list(image.shape), "method": "auto",
                     "input": "dark+noise", "decision": auto(noisy[0], params)[1],
                     **time_ms(cases["auto"], noisy[0], args.runs)})
        for label, pair in (("as recorded", (image, right)), ("dark+noise", noisy)):
            rows.append({"frame": frame_name, "shape": list(image.shape), "method": "auto pair",
                         "input": label, "decision": enhancer(pair[0])[1]["method"],
                         **time_ms(auto_pair, pair, args.runs)})

    header = f"{'frame':<16} {'method':<22} {'input':<14} {'median ms':>10} {'p90 ms':>8} {'min ms':>8}"
    print(header)
    print("-" * len(header))
    for r in rows:
        label = r["method"] + (f"->{r['decision']}" if "decision" in r else "")
        print(f"{r['frame']:<16} {label:<22} {r['input']:<14} {r['median_ms']:>10.3f} {r['p90_ms']:>8.3f} "
              f"{r['min_ms']:>8.3f}")

    result = {
        "benchmark": "bench_enhance_speed",
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "runs": args.runs,
        "machine": {"cpus": os.cpu_count(), "cv2_threads": cv2.getNumThreads(), "python": platform.python_version(),
                    "numpy": np.__version__, "opencv": cv2.__version__, "platform": platform.platform()},
        "params": {k: getattr(params, k) for k in ("omega", "block", "n_dark_pixels", "t0", "tau",
                                                    "usm_alpha", "usm_beta", "usm_sigma", "clahe_clip",
                                                    "clahe_tiles")},
        "targets_ms": {"agri": 3.0, "afe": 2.0, "auto pair": 4.0},
        "load_average": {"before": load_before, "after": os.getloadavg()},
        "rows": rows,
        "pair_rows": pair_rows,
    }
    print(f"\nwrote {write_json(args.out, result)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
