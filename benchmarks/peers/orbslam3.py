"""ORB-SLAM3 stereo as a peer, run on the same frames as Canopy (``pyorbslam3``, optional extra).

    from benchmarks.peers.orbslam3 import available, run_stereo
    ok, how = available()
    res = run_stereo("data/kitti06_snippet", "kitti")          # PeerResult
    res = run_stereo(path, "euroc", preprocess=my_enhance)      # the AFE-ORB-SLAM configuration

ORB-SLAM3 runs in a forked child process: a crash (it aborts on bad settings) or a hang
cannot take the caller down, and its console output goes to a log we parse. Settings
follow issue 8's notes, measured with pyorbslam3 0.1.1:

- rectified input (KITTI, folders): ``Camera.type: PinHole`` with an identical
  ``Camera2``, zero distortion and ``Stereo.T_c1_c2 = [I | (b, 0, 0)]``
  (``Rectified`` crashes while printing the settings); ThDepth 40 as upstream KITTI.
- EuRoC layout: the raw images and the radtan calibration of ``cam0/cam1 sensor.yaml``;
  ORB-SLAM3 rectifies (ThDepth 60, as upstream EuRoC). Generated sequences are in the
  EuRoC layout with zero distortion and go the same way.
- only frames whose tracking state is OK are kept (a briefly lost frame comes back with
  ``pose_valid`` and an identity pose); new maps and resets are counted from its log.
- OK frames whose pose repeats the first OK pose exactly (``frozen_frames``) are not kept
  either: on KITTI's dark hazy grid cells ORB-SLAM3 says OK on 26 of 51 frames while every
  one of them is the identity, the car having driven 25 m (s20-heldout). The issue 9 rule
  "where ORB-SLAM3 tracks at least half the frames" must not count poses that were never
  estimated, the same rule Canopy's own ``trajectory.tum`` follows.

ORB-SLAM3 needs a DBoW2 vocabulary; ``ORBvoc.txt`` cannot be downloaded here, so the first
call trains one with our trainer (``canopy.place``, k=10, L=5) into
``$CANOPY_CACHE_DIR/vocabulary`` (default ``cache/vocabulary``, gitignored) and reuses it.
"""
from __future__ import annotations

import importlib.util
import multiprocessing as mp
import os
import pickle
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Callable

import numpy as np

from canopy.config import REPO_ROOT
from canopy.sources import open_source
from canopy.sources.base import load_yaml_file, numbers
from shared.errors import InputError
from shared.types import Trajectory

DATASETS = ("euroc", "kitti", "folder")
INSTALL_HINT = ("pyorbslam3 is not installed: pip install -e '.[peers]' (GPL-3 wheel with ORB-SLAM3 inside) "
                "and apt-get install -y libgl1 libegl1 libopengl0 libsm6 libice6 libx11-6 libxext6")

# The vocabulary ORB-SLAM3 runs with (issue 8: k=10, L=5 from ~1.2 M descriptors of ~1500
# images closed the generated loops in every run). Same recipe, same file: seed 0.
PEER_VOCABULARY_NAME = "orb_k10_L5.txt"
PEER_VOCABULARY_RECIPE = {"k": 10, "levels": 5, "seed": 0, "max_per_image": 700, "synthetic_stride": 2,
                          "images": ("data/euroc_v101_micro/mav0/cam0/data", "data/kitti06_snippet/image_l"),
                          "presets": ("day-loop", "dusk-loop", "haze-row", "dark-rows")}

# Upstream ORB-SLAM3 example settings (Examples/Stereo/EuRoC.yaml, KITTI00-02.yaml).
TH_DEPTH = {"kitti": 40.0, "folder": 40.0, "euroc": 60.0}
N_FEATURES = {"kitti": 2000, "folder": 2000, "euroc": 1200}
ORB_SCALE_FACTOR, ORB_LEVELS, ORB_INI_FAST, ORB_MIN_FAST = 1.2, 8, 20, 7

LOOP_PATTERN = "*Loop detected"
SHUTDOWN_WAIT_S = 20.0
LOG_TAIL_LINES = 30

Preprocess = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class PeerResult:
    """One ORB-SLAM3 run. ``trajectory``: rectified left camera, TUM stamps, OK frames only."""

    trajectory: Trajectory
    tracked: int                   # frames whose state was OK, frozen ones left out
    total: int                     # frames fed
    track_ms: np.ndarray           # (total,) time of each track_stereo() call
    resets: int                    # new maps + active-map resets after the first map (from its log)
    version: str
    log_tail: str
    loops: int = 0                 # "*Loop detected" lines in its log
    final_trajectory: Trajectory | None = None  # SaveTrajectoryTUM after shutdown (loop-corrected)
    wall_s: float = 0.0            # feeding loop, pacing included
    cpu_s: float = 0.0             # CPU time of the child (all ORB-SLAM3 threads)
    error: str | None = None       # set when the child crashed or timed out
    meta: dict = field(default_factory=dict)
    frozen: int = 0                # OK frames that repeated the first pose exactly (not kept)


FROZEN_POSE_TOL = 1e-9  # an estimate of a moving or even a hovering camera differs far more than this


def frozen_frames(poses: np.ndarray, tol: float = FROZEN_POSE_TOL) -> np.ndarray:
    """Mask of the frames after the first whose 4x4 pose equals the first one to ``tol`` in
    every entry: ORB-SLAM3 reporting OK without having moved its estimate at all."""
    poses = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    if len(poses) == 0:
        return np.zeros(0, bool)
    same = np.all(np.abs(poses - poses[0]) <= tol, axis=(1, 2))
    same[0] = False  # the first pose is the map's origin: a real (initial) estimate
    return same


def available() -> tuple[bool, str]:
    """(True, version) when pyorbslam3 imports; else (False, a one-line how-to-install)."""
    if importlib.util.find_spec("pyorbslam3") is None:
        return False, INSTALL_HINT
    try:
        import pyorbslam3  # noqa: F401
    except Exception as exc:  # a missing system library shows up as an ImportError/OSError here
        return False, f"pyorbslam3 does not import ({type(exc).__name__}: {exc}); {INSTALL_HINT}"
    return True, version()


def version() -> str:
    try:
        return f"pyorbslam3 {metadata.version('pyorbslam3')} (ORB-SLAM3 v1.0)"
    except metadata.PackageNotFoundError:
        return "pyorbslam3 (version unknown)"


# ----------------------------------------------------------------------------- vocabulary

def cache_dir() -> Path:
    return Path(os.environ.get("CANOPY_CACHE_DIR", REPO_ROOT / "cache"))


def peer_vocabulary(vocabulary: str | Path | None = None, progress: bool = True) -> Path:
    """A plain-text DBoW2 vocabulary ORB-SLAM3 can read.

    ``vocabulary``: a file of ours or DBoW2's (text or YAML, gzipped or not); None = the
    cached peer vocabulary, trained on first use (about 2-4 min on one core).
    """
    folder = cache_dir() / "vocabulary"
    if vocabulary is not None:
        path = Path(vocabulary)
        if not path.is_file():
            raise InputError(path, "vocabulary file not found")
        raw = path.read_bytes()[:64]
        if raw[:2] != b"\x1f\x8b" and not raw.lstrip().startswith((b"%YAML", b"vocabulary:")):
            return path  # already plain DBoW2 text
        from canopy.place import Vocabulary
        out = folder / (path.name.removesuffix(".gz").removesuffix(".txt").removesuffix(".yml") + ".txt")
        if not out.is_file() or out.stat().st_mtime < path.stat().st_mtime:
            _atomic_save(Vocabulary.load(path), out)
        return out
    out = folder / PEER_VOCABULARY_NAME
    if out.is_file():
        return out
    from canopy.app import prepare_synthetic
    from canopy.place.training import ImageSource, train_from_images

    r = PEER_VOCABULARY_RECIPE
    sources = [ImageSource(REPO_ROOT / p) for p in r["images"]]
    sources += [ImageSource(Path(prepare_synthetic(p, None, 0, progress)) / "mav0" / "cam0" / "data",
                            r["synthetic_stride"]) for p in r["presets"]]
    if progress:
        print(f"  training the ORB-SLAM3 vocabulary (k={r['k']}, L={r['levels']}) into {out} ...", flush=True)
    vocab, record = train_from_images(sources, "orb", r["k"], r["levels"], r["seed"], r["max_per_image"])
    _atomic_save(vocab, out)
    import json
    out.with_suffix(".json").write_text(json.dumps(record, indent=1) + "\n")
    return out


def _atomic_save(vocab, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    vocab.save(tmp)
    os.replace(tmp, out)


# ----------------------------------------------------------------------------- settings

def _real(v: float) -> str:
    """A number OpenCV's FileStorage reads as real: "0" would be an int, and ORB-SLAM3
    aborts on an int where it wants a real ("Camera1.k1 parameter must be a real number")."""
    text = f"{float(v):.10g}"
    return text if any(c in text for c in ".en") else text + ".0"


def _matrix(rows: int, cols: int, values) -> str:
    data = ", ".join(_real(v) for v in np.asarray(values).ravel())
    return f"!!opencv-matrix\n  rows: {rows}\n  cols: {cols}\n  dt: f\n  data: [{data}]"


def _camera_block(name: str, K: np.ndarray, D: np.ndarray) -> list[str]:
    d = np.zeros(4) if D is None else np.asarray(D, np.float64).ravel()
    lines = [f"{name}.fx: {_real(K[0, 0])}", f"{name}.fy: {_real(K[1, 1])}",
             f"{name}.cx: {_real(K[0, 2])}", f"{name}.cy: {_real(K[1, 2])}",
             f"{name}.k1: {_real(d[0])}", f"{name}.k2: {_real(d[1])}",
             f"{name}.p1: {_real(d[2])}", f"{name}.p2: {_real(d[3])}"]
    if d.size > 4:
        lines.append(f"{name}.k3: {_real(d[4])}")
    return lines


def _euroc_camera(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data = load_yaml_file(path)
    fu, fv, cu, cv = numbers(data.get("intrinsics"), 4, path, "intrinsics")
    D = numbers(data.get("distortion_coefficients"), None, path, "distortion_coefficients")
    t_bs = data.get("T_BS")
    T = numbers(t_bs.get("data") if isinstance(t_bs, dict) else t_bs, 16, path, "T_BS").reshape(4, 4)
    return np.array([[fu, 0, cu], [0, fv, cv], [0, 0, 1.0]]), D, T


def settings_yaml(source, dataset: str) -> tuple[str, bool]:
    """(ORB-SLAM3 settings text, whether to feed raw pairs) for an opened Canopy source."""
    cal = source.calibration
    fps = max(1, int(round(source.rate_hz)))
    kind = "euroc" if dataset == "euroc" else dataset
    if dataset == "euroc":
        mav0 = source.left_paths[0].parents[2]
        K0, D0, T_B_c0 = _euroc_camera(mav0 / "cam0" / "sensor.yaml")
        K1, D1, T_B_c1 = _euroc_camera(mav0 / "cam1" / "sensor.yaml")
        T_c1_c2 = np.linalg.inv(T_B_c0) @ T_B_c1
        cams = _camera_block("Camera1", K0, D0) + _camera_block("Camera2", K1, D1)
        raw = True
    else:
        K = cal.K
        cams = _camera_block("Camera1", K, None) + _camera_block("Camera2", K, None)
        T_c1_c2 = np.eye(4)
        T_c1_c2[0, 3] = cal.baseline
        raw = False
    lines = ["%YAML:1.0", 'File.version: "1.0"', 'Camera.type: "PinHole"', *cams,
             f"Camera.width: {cal.width}", f"Camera.height: {cal.height}", f"Camera.fps: {fps}",
             "Camera.RGB: 0", f"Stereo.ThDepth: {_real(TH_DEPTH[kind])}",
             f"Stereo.T_c1_c2: {_matrix(4, 4, T_c1_c2)}",
             f"ORBextractor.nFeatures: {N_FEATURES[kind]}", f"ORBextractor.scaleFactor: {ORB_SCALE_FACTOR}",
             f"ORBextractor.nLevels: {ORB_LEVELS}", f"ORBextractor.iniThFAST: {ORB_INI_FAST}",
             f"ORBextractor.minThFAST: {ORB_MIN_FAST}",
             "Viewer.KeyFrameSize: 0.05", "Viewer.KeyFrameLineWidth: 1.0", "Viewer.GraphLineWidth: 0.9",
             "Viewer.PointSize: 2.0", "Viewer.CameraSize: 0.08", "Viewer.CameraLineWidth: 3.0",
             "Viewer.ViewpointX: 0.0", "Viewer.ViewpointY: -0.7", "Viewer.ViewpointZ: -1.8",
             "Viewer.ViewpointF: 500.0"]
    return "\n".join(lines) + "\n", raw


# ----------------------------------------------------------------------------- the run

def _child(result_path: str, log_path: str, sequence, dataset: str, preprocess, vocab: str,
           max_frames, pace: bool) -> None:
    """Runs in the forked process: stdout/stderr of ORB-SLAM3 go to ``log_path``."""
    log_fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(log_fd, 1)
    os.dup2(log_fd, 2)
    import pyorbslam3 as pos

    source = open_source(dataset, sequence, max_frames=max_frames)
    text, raw = settings_yaml(source, dataset)
    work = Path(result_path).parent
    settings = work / "orbslam3.yaml"
    settings.write_text(text)
    slam = pos.Slam(vocab, str(settings), pos.Sensor.STEREO)
    n = len(source)
    track_ms = np.full(n, np.nan)
    ok_stamps, ok_poses = [], []
    period = 1.0 / source.rate_hz if source.rate_hz > 0 else 0.0
    from actors.schedstat import thread_report, thread_schedstat
    sched0 = thread_schedstat()  # the calling thread runs ORB-SLAM3's tracking (in a fork: tid = pid)
    wall0 = time.perf_counter()
    for i in range(n):
        left, right = source.raw_pair(i) if raw else (lambda f: (f.left, f.right))(source.frame(i))
        if preprocess is not None:
            left, right = preprocess(left, right)
        t0 = time.perf_counter()
        res = slam.track_stereo(np.ascontiguousarray(left), np.ascontiguousarray(right),
                                float(source.timestamps[i]))
        dt = time.perf_counter() - t0
        track_ms[i] = dt * 1e3
        if res.state == pos.TrackingState.OK and res.pose_valid:
            ok_stamps.append(float(source.timestamps[i]))
            ok_poses.append(np.asarray(res.pose_wc, np.float64).reshape(4, 4))
        if pace and dt < period:  # upstream examples feed at the sequence rate
            time.sleep(period - dt)
    wall = time.perf_counter() - wall0
    threads = thread_report(sched0, thread_schedstat(), {os.getpid(): "tracking"}, n)
    slam.shutdown()
    deadline = time.monotonic() + SHUTDOWN_WAIT_S
    while not slam.is_shutdown() and time.monotonic() < deadline:
        time.sleep(0.05)
    cpu = os.times()
    result = {"stamps": ok_stamps, "poses": ok_poses, "track_ms": track_ms, "total": n, "wall_s": wall,
              "cpu_s": cpu.user + cpu.system, "final": None, "settings": text, "threads": threads}
    # Written before SaveTrajectoryTUM, which can crash (SIGSEGV seen after ORB-SLAM3 started a
    # second map on dusk-loop): the online trajectory survives, only the final one is lost.
    with open(result_path, "wb") as f:
        pickle.dump(result, f)
    final = None
    try:
        tum = work / "final.tum"
        slam.save_trajectory_tum(str(tum))
        rows = np.loadtxt(tum, ndmin=2)
        if len(rows):
            from shared.geometry import poses_from_xyz_quat_wxyz
            q_wxyz = rows[:, [7, 4, 5, 6]]
            final = (rows[:, 0], poses_from_xyz_quat_wxyz(rows[:, 1:4], q_wxyz))
    except Exception as exc:  # the online trajectory is the main result; say why this one is missing
        print(f"[peer] final trajectory not saved: {exc}", flush=True)
    if final is not None:
        result["final"] = final
        with open(result_path, "wb") as f:
            pickle.dump(result, f)
    os._exit(0)  # skip ORB-SLAM3's static destructors (they can hang after shutdown)


def run_stereo(sequence: str | Path | None, dataset: str, *, preprocess: Preprocess | None = None,
               vocabulary: str | Path | None = None, max_frames: int | None = None,
               timeout_s: float = 900.0, pace: bool = True) -> PeerResult:
    """Run ORB-SLAM3 stereo on a Canopy-readable sequence in a child process.

    ``sequence``: the dataset folder (None = the bundled snippet for euroc/kitti).
    ``preprocess(left, right) -> (left, right)`` is applied to every pair before tracking
    (in the child; any callable works, the child is forked). ``pace``: feed at the
    sequence's frame rate as the upstream examples do (tracking time is measured per
    call either way).
    """
    if dataset not in DATASETS:
        raise InputError("dataset", f"unknown dataset {dataset!r}; choose one of {DATASETS}")
    ok, how = available()
    if not ok:
        raise RuntimeError(how)
    vocab = str(peer_vocabulary(vocabulary))
    src = open_source(dataset, sequence, max_frames=max_frames)  # validate before forking
    gt_frame_stamps = src.timestamps
    work = Path(tempfile.mkdtemp(prefix="canopy_orbslam3_"))
    result_path, log_path = work / "result.pkl", work / "orbslam3.log"
    ctx = mp.get_context("fork")
    proc = ctx.Process(target=_child, args=(str(result_path), str(log_path), sequence, dataset, preprocess,
                                            vocab, max_frames, pace), daemon=True)
    proc.start()
    proc.join(timeout_s)
    error = None
    if proc.is_alive():
        proc.kill()
        proc.join(5)
        error = f"timed out after {timeout_s:.0f} s"
    elif not result_path.is_file():
        error = f"ORB-SLAM3 child exited with code {proc.exitcode} before writing a result"
    final_note = (f"child exited with code {proc.exitcode} while saving its final trajectory"
                  if error is None and proc.exitcode != 0 else None)
    log = log_path.read_text(errors="replace") if log_path.is_file() else ""
    tail = "\n".join(log.splitlines()[-LOG_TAIL_LINES:])
    meta = {"vocabulary": vocab, "sequence": str(src.root), "dataset": dataset, "pace": pace,
            "preprocess": getattr(preprocess, "__name__", None) if preprocess else None}
    if error is not None:
        shutil.rmtree(work, ignore_errors=True)
        return PeerResult(Trajectory(np.zeros(0), np.zeros((0, 4, 4))), 0, len(gt_frame_stamps),
                          np.zeros(0), 0, version(), tail, error=error, meta=meta)
    with open(result_path, "rb") as f:
        r = pickle.load(f)
    shutil.rmtree(work, ignore_errors=True)
    maps = log.count("Creation of new map with id:")
    resets = max(maps - 1, 0) + log.count("Active map Reseting") + log.count("Reseting Atlas")
    poses = np.asarray(r["poses"], np.float64).reshape(-1, 4, 4)
    keep = ~frozen_frames(poses)
    traj = Trajectory(np.asarray(r["stamps"], np.float64)[keep], poses[keep],
                      meta={"frame": "rectified left camera", "system": "orbslam3"})
    final = Trajectory(*r["final"], meta={"system": "orbslam3", "kind": "final"}) if r["final"] else None
    meta["settings"] = r["settings"]
    meta["threads"] = r.get("threads") or {}  # per-thread CPU / run-queue wait (actors.schedstat)
    meta["final_trajectory_error"] = final_note
    return PeerResult(traj, len(traj), r["total"], np.asarray(r["track_ms"]), resets, version(), tail,
                      loops=log.count(LOOP_PATTERN), final_trajectory=final, wall_s=r["wall_s"],
                      cpu_s=r["cpu_s"], meta=meta, frozen=int((~keep).sum()))
