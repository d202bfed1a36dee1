#!/usr/bin/env python
"""A real motion-compensated temporal denoiser on a degraded generated cell, against the exact-warp oracle
(issue 9, s22; ``benchmarks/oracle_temporal.py``). An experiment, not shipped: docs/notes/s22-temporal.md.

The filter: a first-order recursive filter per camera with motion compensation (Dubois & Sabri, "Noise
reduction in image sequences using motion-compensated temporal filtering", IEEE Trans. Comm. 32(7), 1984):

    out_t = I_t + a·w·(warp(out_{t−1}) − I_t),   w = max(0, 1 − |G * (warp(out_{t−1}) − I_t)| / (k·σ))

* ``warp``: dense optical flow from I_t to I_{t−1} (DIS, Kroeger et al., ECCV 2016: OpenCV's
  ``DISOpticalFlow``) on copies downscaled by ``downsample`` (INTER_AREA), upsampled and applied to the
  previous *output* by bilinear remap; pixels whose flow leaves the image keep the current frame.
* ``w``: where the compensated past disagrees with the present by more than the noise explains (wrong
  flow, occlusion, a moving edge) the past is dropped, so edges do not ghost; the difference is smoothed
  by a Gaussian G (σ 1 px) first so that a correct warp's noise passes.
* ``a``: the weight of the past; on a correct warp the output's noise variance is (1 − a)/(1 + a) of
  the input's at steady state (a = 0.6: ¼, as averaging 4 frames).
* σ: the raw left frame's noise (``canopy.enhance.noise.estimate_noise``), both cameras alike.

Modes:
    --filter W,K,F[,PRESET] --cell C --out O [--run]   filter both cameras of a cell, track it in process
                                                        (PRESET ultrafast / fast / medium, or exact: the oracle's warp)
    --flow-accuracy --cell C                            DIS end-point error against the exact warp
    --cpu --cell C                                      CPU per pair (time.thread_time)
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from canopy.enhance.noise import estimate_noise  # noqa: E402
from canopy.frontend.geometry import se3_inv  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from oracle_temporal import load_depth, track  # noqa: E402
from oracle_temporal import warp_maps  # noqa: E402

PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
           "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


class TemporalFilter:
    """One camera's recursive filter: ``filter(grey, sigma) -> grey'`` (uint8); ``reset()`` forgets the past."""

    def __init__(self, weight: float = 0.6, k: float = 2.0, downsample: int = 2, blur_sigma: float = 1.0,
                 preset: str = "ultrafast"):
        if not 0.0 <= weight < 1.0:
            raise ValueError(f"TemporalFilter: weight must be in [0, 1), got {weight}")
        if k <= 0.0 or downsample < 1 or blur_sigma < 0.0:
            raise ValueError("TemporalFilter: k > 0, downsample >= 1 and blur_sigma >= 0 required")
        if preset not in PRESETS:
            raise ValueError(f"TemporalFilter: preset must be one of {', '.join(PRESETS)}, got {preset!r}")
        self.weight, self.k, self.downsample, self.blur_sigma = float(weight), float(k), int(downsample), float(blur_sigma)
        self._flow = cv2.DISOpticalFlow_create(PRESETS[preset])
        self._grid = None
        self.reset()

    def reset(self) -> None:
        self._prev_out = None     # float32, full resolution
        self._prev_small = None   # uint8, downscaled raw frame

    def _small(self, grey: np.ndarray) -> np.ndarray:
        f = self.downsample
        if f == 1:
            return grey
        h, w = grey.shape
        return cv2.resize(grey[: h - h % f, : w - w % f], (w // f, h // f), interpolation=cv2.INTER_AREA)

    def filter(self, grey: np.ndarray, sigma: float, flow: np.ndarray | None = None) -> np.ndarray:
        """``flow``: a full-resolution flow (H, W, 2) to use instead of DIS's, NaN where the past is not seen
        (the exact warp of the oracle: separates the flow's error from the filter's)."""
        if grey.ndim != 2 or grey.dtype != np.uint8:
            raise ValueError("TemporalFilter: an 8-bit grey image is required")
        small = self._small(grey)
        cur = grey.astype(np.float32)
        if self._prev_out is None or self._prev_out.shape != cur.shape:
            self._prev_out, self._prev_small = cur, small
            return grey
        h, w = grey.shape
        f = self.downsample
        if flow is None:
            flow = self._flow.calc(small, self._prev_small, None)  # I_t(x) ≈ I_{t−1}(x + flow(x))
        elif f > 1:
            f = 1  # given at full resolution
        if f > 1:
            flow = cv2.resize(flow, (w, h), interpolation=cv2.INTER_LINEAR) * float(f)
        if self._grid is None or self._grid[0].shape != (h, w):
            self._grid = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
        mx, my = self._grid[0] + flow[..., 0], self._grid[1] + flow[..., 1]
        warped = cv2.remap(self._prev_out, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                           borderValue=float("nan"))  # out of view: NaN, weight 0 below
        diff = warped - cur
        np.nan_to_num(diff, copy=False, nan=1e6)
        local = cv2.GaussianBlur(diff, (0, 0), self.blur_sigma) if self.blur_sigma > 0 else diff
        wgt = np.clip(1.0 - np.abs(local) / (self.k * max(float(sigma), 1e-3)), 0.0, 1.0)
        wgt[np.abs(diff) >= 1e5] = 0.0
        out = cur + (self.weight * wgt) * np.where(wgt > 0, diff, 0.0)
        self._prev_out, self._prev_small = out, small
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def exact_flows(cell: Path):
    """Per camera, frame t -> the exact flow from t to t−1 (``oracle_temporal.warp_maps``), NaN where occluded."""
    from canopy.degrade import depth_from_rendered
    src = open_source("euroc", cell)
    c = src.calibration
    K = np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]])
    gt, depth_l = src.ground_truth.poses, load_depth(cell)
    depth_r = [depth_from_rendered(d, c, view="right") for d in depth_l]
    T_lr = np.eye(4)
    T_lr[0, 3] = c.baseline
    gx, gy = np.meshgrid(np.arange(c.width, dtype=np.float32), np.arange(c.height, dtype=np.float32))

    def flow(cam: int, t: int):
        depth, T_c = (depth_l, np.eye(4)) if cam == 0 else (depth_r, T_lr)
        mx, my, ok = warp_maps(depth[t], depth[t - 1], se3_inv(gt[t - 1] @ T_c) @ gt[t] @ T_c, K, 0.03)
        fl = np.dstack([mx - gx, my - gy]).astype(np.float32)
        fl[~ok] = np.nan
        return fl
    return flow


def filter_folder(cell: Path, out: Path, weight: float, k: float, downsample: int, preset: str = "ultrafast") -> dict:
    """The filter on every frame of both cameras of ``cell``, written as a new sequence folder ``out``;
    ``preset`` "exact": the oracle's exact flow instead of DIS."""
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(cell, out, ignore=shutil.ignore_patterns("*.png"))
    shutil.copytree(cell / "mav0" / "depth0" / "data", out / "mav0" / "depth0" / "data", dirs_exist_ok=True)
    f0 = sorted((cell / "mav0" / "cam0" / "data").iterdir())
    f1 = sorted((cell / "mav0" / "cam1" / "data").iterdir())
    exact = exact_flows(cell) if preset == "exact" else None
    filters = [TemporalFilter(weight, k, downsample, preset="ultrafast" if exact else preset) for _ in range(2)]
    sig = []
    for t, (a, b) in enumerate(zip(f0, f1)):
        left, right = cv2.imread(str(a), cv2.IMREAD_UNCHANGED), cv2.imread(str(b), cv2.IMREAD_UNCHANGED)
        sigma = estimate_noise(left, rows_fraction=0.5)
        sig.append(sigma)
        fl = (exact(0, t), exact(1, t)) if exact and t > 0 else (None, None)
        cv2.imwrite(str(out / "mav0" / "cam0" / "data" / a.name), filters[0].filter(left, sigma, fl[0]))
        cv2.imwrite(str(out / "mav0" / "cam1" / "data" / b.name), filters[1].filter(right, sigma, fl[1]))
    return {"frames": len(f0), "raw_sigma_p50": float(np.median(sig))}


def flow_accuracy(cell: Path, frames=(20, 40, 60, 79)) -> list[dict]:
    """DIS's end-point error (px, left camera, frame t against t−1) against the exact warp, per preset and scale."""
    src = open_source("euroc", cell, max_frames=max(frames) + 1)
    c = src.calibration
    K = np.array([[c.fx, 0, c.cx], [0, c.fy, c.cy], [0, 0, 1.0]])
    gt, depth = src.ground_truth.poses, load_depth(cell)
    rows = []
    for name, preset in PRESETS.items():
        for f in (2, 4):
            dis = cv2.DISOpticalFlow_create(preset)
            errs, ts = [], []
            for t in frames:
                mx, my, ok = warp_maps(depth[t], depth[t - 1], se3_inv(gt[t - 1]) @ gt[t], K, 0.03)
                h, w = mx.shape
                a, b = (cv2.resize(src.frame(i).left, (w // f, h // f), interpolation=cv2.INTER_AREA) for i in (t, t - 1))
                t0 = time.thread_time()
                fl = dis.calc(a, b, None)
                ts.append(time.thread_time() - t0)
                fl = cv2.resize(fl, (w, h)) * f
                gx, gy = np.meshgrid(np.arange(w), np.arange(h))
                errs.append(np.hypot(gx + fl[..., 0] - mx, gy + fl[..., 1] - my)[ok])
            e = np.concatenate(errs)
            rows.append({"preset": name, "downsample": f, "epe_p50": float(np.median(e)),
                         "epe_p90": float(np.percentile(e, 90)), "epe_mean": float(e.mean()),
                         "flow_ms": 1e3 * float(np.median(ts))})
    return rows


def cpu_per_pair(cell: Path, frames: int = 60, **kw) -> dict:
    src = open_source("euroc", cell, max_frames=frames)
    pairs = [src.frame(i) for i in range(frames)]
    filters = [TemporalFilter(**kw) for _ in range(2)]
    ts = []
    for fr in pairs:
        t0 = time.thread_time()
        sigma = estimate_noise(fr.left, rows_fraction=0.5)
        filters[0].filter(fr.left, sigma)
        filters[1].filter(fr.right, sigma)
        ts.append(time.thread_time() - t0)
    return {"cpu_ms_p50": 1e3 * float(np.median(ts[1:])), "cpu_ms_mean": 1e3 * float(np.mean(ts[1:]))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cell", required=True)
    ap.add_argument("--filter", default=None, help="WEIGHT,K,DOWNSAMPLE[,PRESET]")
    ap.add_argument("--out", default=None)
    ap.add_argument("--run", action="store_true")
    ap.add_argument("--flow-accuracy", action="store_true")
    ap.add_argument("--cpu", action="store_true")
    args = ap.parse_args()
    cell = Path(args.cell)
    if args.flow_accuracy:
        for r in flow_accuracy(cell):
            print(json.dumps(r))
    if args.cpu:
        for preset in ("ultrafast", "medium"):
            print(json.dumps({"preset": preset, **cpu_per_pair(cell, preset=preset)}))
    if args.filter:
        if not args.out:
            raise SystemExit("--filter needs --out")
        wgt, k, ds, *preset = args.filter.split(",")
        info = filter_folder(cell, Path(args.out), float(wgt), float(k), int(ds), *preset)
        if args.run:
            info.update(track(cell, Path(args.out)))
        print(json.dumps({"cell": cell.name, "filter": args.filter, **info}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
