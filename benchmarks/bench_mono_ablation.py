"""AFE-ORB-SLAM Table 2 as an ablation of Canopy's monocular mode, with ORB-SLAM3 monocular beside it.

Configurations (AFE-ORB-SLAM §5, Table 2): ``none``; ``he`` and ``clahe`` pre-processing;
``afe-enh``: the truncated AGCWD + unsharp masking alone (Eq. 1-17, fixed FAST threshold);
``afast``: the adaptive FAST threshold alone (Eq. 18-19, raw frames); ``afe``: both.
Every configuration runs the in-process lockstep monocular pipeline
(``canopy.mono.pipeline.run_mono_sequential``) on the left images. ORB-SLAM3 monocular
(``pyorbslam3``, when importable, in a forked child; PinHole settings from the rectified
calibration, the shared self-trained vocabulary ``$CANOPY_CACHE_DIR/vocabulary/orb_k10_L5.txt``)
runs on the raw frames of the same sequences.

Sequences: the KITTI 06 snippet, a darkened copy of it (``canopy.degrade.darken``, gain
``--gain``, fixed seed per frame), the static EuRoC snippet, and generated presets
(``--presets``, first ``--max-frames`` frames). Reported per run: frame of initialisation,
tracked % after it, Sim(3) ATE RMSE over tracked frames with its scale, keyframes, wall time.

    CANOPY_CACHE_DIR=/work/cache python benchmarks/bench_mono_ablation.py [--presets dusk-loop dark-rows] [--max-frames 300]

Timing on a shared machine is noisy: wall time is reported for orientation only.
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import pickle
import platform
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.config import load_run_config  # noqa: E402
from canopy.degrade import darken  # noqa: E402
from canopy.enhance import EnhanceParams, adaptive_fast_threshold, fallback_fast_threshold, make_enhancer  # noqa: E402
from canopy.metrics import associate, ate_sim3  # noqa: E402
from canopy.mono.pipeline import run_mono_sequential  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from shared.types import StereoFrame  # noqa: E402

# configuration -> (enhancement method, adaptive FAST threshold)
CONFIGS = {"none": ("none", False), "he": ("he", False), "clahe": ("clahe", False),
           "afe-enh": ("afe", False), "afast": ("none", True), "afe": ("afe", True)}
PEER_VOCABULARY = "orb_k10_L5.txt"
ORB_N_FEATURES = {"kitti": 2000, "euroc": 1000}


class ImageSource:
    """A source whose left images go through ``transform`` (darkening and/or enhancement)."""

    def __init__(self, source, transform=None):
        self.source, self.transform = source, transform
        self.calibration, self.timestamps = source.calibration, source.timestamps
        self.ground_truth, self.rate_hz = source.ground_truth, source.rate_hz

    def __len__(self) -> int:
        return len(self.source)

    def left(self, i: int) -> np.ndarray:
        img = self.source.frame(i).left
        return img if self.transform is None else self.transform(i, img)

    def frame(self, i: int) -> StereoFrame:
        f = self.source.frame(i)
        left = f.left if self.transform is None else self.transform(i, f.left)
        return StereoFrame(f.index, f.timestamp, left, left)  # monocular: the right image is never read


def sequences(args) -> dict[str, tuple[str, str | None, int | None, float | None]]:
    """name -> (dataset kind, path, max frames, darkening gain)."""
    seqs = {"kitti06": ("kitti", None, None, None), f"kitti06-dark x{args.gain:g}": ("kitti", None, None, args.gain),
            "euroc-static": ("euroc", None, None, None)}
    if args.presets:
        from canopy.app import prepare_synthetic
        for preset in args.presets:
            seqs[preset] = ("euroc", prepare_synthetic(preset, None, 0, False), args.max_frames, None)
    return seqs


def _evaluate(stamps, poses, tracked, gt) -> dict:
    out = {"ate_sim3_m": None, "scale": None, "path_m": None}
    if gt is None or tracked.sum() < 3:
        return out
    ia, ib = associate(np.asarray(stamps)[tracked], gt.stamps, 0.01)
    if len(ia) < 3:
        return out
    a = ate_sim3(np.asarray(poses)[tracked][ia], gt.poses[ib])
    g = gt.poses[ib][:, :3, 3]
    out.update(ate_sim3_m=a["rmse"], scale=a["scale"], path_m=float(np.linalg.norm(np.diff(g, axis=0), axis=1).sum()))
    return out


def run_canopy(source, dataset: str, config: str) -> dict:
    method, adaptive = CONFIGS[config]
    enhance = make_enhancer(EnhanceParams(method=method)) if method != "none" else None
    ep = EnhanceParams()
    base = source.transform

    def transform(i, img):
        img = img if base is None else base(i, img)
        return img if enhance is None else enhance(img)[0]

    src = ImageSource(source.source, transform)
    def adaptive_fast(img):  # AFE Eq. 18 on the frame tracking sees, Eq. 19 when too few corners
        return (adaptive_fast_threshold(img, ep.fast_omega), fallback_fast_threshold(img, ep.fast_omega),
                ep.min_keypoints)
    fast = adaptive_fast if adaptive else None
    t0 = time.perf_counter()
    cfg = load_run_config(dataset)
    res = run_mono_sequential(src, cfg.tracking, cfg.mono, fast=fast)
    wall = time.perf_counter() - t0
    st = np.array(res.statuses)
    init = res.first_initialised
    after = st[init:] if init is not None else st[:0]
    row = {"system": "canopy", "config": config, "frames": len(st), "init_frame": init,
           "tracked_after_init_pct": float(100 * np.mean(after == "ok")) if len(after) else 0.0,
           "initialisations": res.n_initialisations, "keyframes": len(res.keyframe_indices), "wall_s": wall}
    row.update(_evaluate(res.trajectory.stamps, res.trajectory.poses, res.tracked_mask, src.ground_truth))
    return row


# ----------------------------------------------------------------------------- ORB-SLAM3 monocular

def _real(v: float) -> str:
    text = f"{float(v):.10g}"
    return text if any(c in text for c in ".en") else text + ".0"   # OpenCV must read a real


def orbslam3_mono_settings(calib, rate_hz: float, n_features: int) -> str:
    """ORB-SLAM3 v1.0 settings for a rectified pinhole camera without distortion (monocular)."""
    return "\n".join([
        "%YAML:1.0", 'File.version: "1.0"', 'Camera.type: "PinHole"',
        f"Camera1.fx: {_real(calib.fx)}", f"Camera1.fy: {_real(calib.fy)}",
        f"Camera1.cx: {_real(calib.cx)}", f"Camera1.cy: {_real(calib.cy)}",
        "Camera1.k1: 0.0", "Camera1.k2: 0.0", "Camera1.p1: 0.0", "Camera1.p2: 0.0",
        f"Camera.width: {calib.width}", f"Camera.height: {calib.height}",
        f"Camera.fps: {max(1, int(round(rate_hz)))}", "Camera.RGB: 0",
        f"ORBextractor.nFeatures: {n_features}", "ORBextractor.scaleFactor: 1.2", "ORBextractor.nLevels: 8",
        "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7",
        "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8", "Viewer.ViewpointF: 500.0"]) + "\n"


def _orbslam3_child(result_path: str, log_path: str, source: ImageSource, vocab: str, n_features: int) -> None:
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    import pyorbslam3 as pos

    settings = Path(result_path).with_name("mono.yaml")
    settings.write_text(orbslam3_mono_settings(source.calibration, source.rate_hz, n_features))
    slam = pos.Slam(vocab, str(settings), pos.Sensor.MONOCULAR)
    stamps, poses, t0 = [], [], time.perf_counter()
    for i in range(len(source)):
        r = slam.track_monocular(np.ascontiguousarray(source.left(i)), float(source.timestamps[i]))
        if r.state == pos.TrackingState.OK and r.pose_valid:
            stamps.append(float(source.timestamps[i]))
            poses.append(np.asarray(r.pose_wc, np.float64).reshape(4, 4))
    wall = time.perf_counter() - t0
    slam.shutdown()
    with open(result_path, "wb") as f:
        pickle.dump({"stamps": stamps, "poses": poses, "wall_s": wall, "total": len(source)}, f)
    os._exit(0)   # ORB-SLAM3's static destructors can hang after shutdown


def run_orbslam3(source: ImageSource, dataset: str, timeout_s: float = 900.0) -> dict | None:
    vocab = Path(os.environ.get("CANOPY_CACHE_DIR", ROOT / "cache")) / "vocabulary" / PEER_VOCABULARY
    try:
        import pyorbslam3  # noqa: F401  (optional peer: skipped when it does not import)
    except Exception:
        return None
    if not vocab.is_file():
        return {"system": "orbslam3", "config": "none", "error": f"no vocabulary at {vocab}"}
    work = Path(tempfile.mkdtemp(prefix="canopy_orb3mono_"))
    proc = mp.get_context("fork").Process(target=_orbslam3_child, daemon=True, args=(
        str(work / "result.pkl"), str(work / "log.txt"), source, str(vocab), ORB_N_FEATURES[dataset]))
    proc.start()
    proc.join(timeout_s)
    if proc.is_alive():
        proc.kill()
        proc.join(5)
    row = {"system": "orbslam3", "config": "none (raw)", "frames": len(source)}
    if not (work / "result.pkl").is_file():
        tail = (work / "log.txt").read_text(errors="replace")[-300:] if (work / "log.txt").is_file() else ""
        row["error"] = f"child exit {proc.exitcode}: {tail}"
        return row
    r = pickle.loads((work / "result.pkl").read_bytes())
    stamps = np.asarray(r["stamps"])
    first = int(np.searchsorted(source.timestamps, stamps[0])) if len(stamps) else None
    row.update(init_frame=first, initialisations=None, keyframes=None, wall_s=r["wall_s"],
               tracked_after_init_pct=100.0 * len(stamps) / (len(source) - first) if first is not None else 0.0)
    poses = np.asarray(r["poses"]).reshape(-1, 4, 4)
    row.update(_evaluate(stamps, poses, np.ones(len(stamps), bool), source.ground_truth))
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", nargs="*", default=["dusk-loop", "dark-rows"])
    ap.add_argument("--max-frames", type=int, default=300, help="frames of each generated preset")
    ap.add_argument("--gain", type=float, default=0.15, help="darkening gain of the KITTI copy")
    ap.add_argument("--configs", nargs="*", default=list(CONFIGS), choices=list(CONFIGS),
                    help="Canopy configurations to run (none given: ORB-SLAM3 only)")
    ap.add_argument("--no-peer", action="store_true", help="skip ORB-SLAM3")
    ap.add_argument("--peer-reps", type=int, default=3, help="ORB-SLAM3 runs per sequence (it is not deterministic)")
    ap.add_argument("--only", nargs="*", default=None, help="run only the sequences whose name starts with one of these")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_mono_ablation.json"))
    args = ap.parse_args(argv)

    rows = []
    header = f"{'sequence':22s} {'system':9s} {'config':10s} {'init@':>5s} {'tracked%':>8s} {'ATE Sim3 m':>10s} {'scale':>7s} {'KFs':>4s} {'wall s':>7s}"
    print(header)
    print("-" * len(header))
    for name, (dataset, path, max_frames, gain) in sequences(args).items():
        if args.only and not any(name.startswith(o) for o in args.only):
            continue
        base = open_source(dataset, path, max_frames=max_frames)
        dark = None if gain is None else (lambda i, img, g=gain: darken(img, g, rng=1000 + i))
        source = ImageSource(base, dark)
        runs = [run_canopy(source, dataset, c) for c in args.configs]
        for rep in range(0 if args.no_peer else args.peer_reps):   # ORB-SLAM3 is not deterministic
            peer = run_orbslam3(source, dataset)
            if peer is None:
                break
            peer["rep"] = rep
            runs.append(peer)
        for row in runs:
            row["sequence"] = name
            rows.append(row)

            def f(v, fmt):
                return format(v, fmt) if v is not None else "-"
            print(f"{name:22s} {row['system']:9s} {row['config']:10s} {f(row.get('init_frame'), '5d')} "
                  f"{f(row.get('tracked_after_init_pct'), '8.1f')} {f(row.get('ate_sim3_m'), '10.3f')} "
                  f"{f(row.get('scale'), '7.2f')} {f(row.get('keyframes'), '4d')} {f(row.get('wall_s'), '7.1f')}"
                  + (f"  error: {row['error']}" if row.get("error") else ""), flush=True)
        write_json(Path(args.out), {"benchmark": "bench_mono_ablation", "rows": rows,
                                    "when": datetime.now(timezone.utc).isoformat(), "machine": platform.platform(),
                                    "cpu_count": os.cpu_count(), "argv": sys.argv[1:],
                                    "note": "wall time measured on a shared machine: orientation only"})
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
