"""Render a whole sequence and write it in the EuRoC ASL layout.

    <out>/mav0/cam0/{sensor.yaml, data.csv, data/<stamp_ns>.png}   left, rectified
    <out>/mav0/cam1/{sensor.yaml, data.csv, data/<stamp_ns>.png}   right
    <out>/mav0/depth0/{sensor.yaml, data.csv, data/<stamp_ns>.png} left depth, uint16 mm, 0 = none
    <out>/mav0/state_groundtruth_estimate0/data.csv                 T_world_body, body = cam0
    <out>/params.json                                               stamp, written last

Body frame = camera 0 (T_BS identity); cam1 sits at +baseline along x with no
rotation and zero distortion, so any EuRoC reader's rectification is the
identity and the ground truth is directly ``T_world_cam`` of the left camera.
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict
from multiprocessing import get_context
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from shared.errors import InputError

from .conditions import Conditions, light_schedule
from .presets import SyntheticParams, resolve_params
from .renderer import Renderer, RenderOutput
from .scene import Layout, OrchardScene
from .trajectories import CameraTrack, frames_for_length, make_track, path_for

GENERATOR = "canopy.synthetic"
VERSION = 1  # bump when the rendering changes, to invalidate cached sequences
STAMP_FILE = "params.json"
PARTIAL_FILE = ".generating"  # present while a generation runs (or after one was interrupted)
DEPTH_SCALE = 1000.0  # depth PNG units per metre
# Huffman-only deflate: ~2x faster than level 1 and smaller on noisy images.
PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]


class SequenceGenerator:
    """Scene, trajectory and renderers of one parameter set; renders frames on demand."""

    def __init__(self, params: SyntheticParams, seed: int = 0):
        self.params = params
        self.seed = int(seed)
        p = params
        layout = Layout(n_rows=p.n_rows, row_spacing=p.row_spacing, row_length=p.row_length,
                        tree_spacing=p.tree_spacing)
        self.scene = OrchardScene(layout, seed=self.seed, low_texture_x=p.low_texture)
        self.calibration = p.calibration
        n = p.n_frames
        if n == 0:
            length = p.length_m if p.length_m > 0 else path_for(self.scene).perimeter + p.revisit_m
            n = frames_for_length(length, p.speed, p.rate_hz)
        self.n_frames = n
        self.track: CameraTrack = make_track(self.scene, n, p.rate_hz, speed=p.speed, seed=self.seed,
                                             cam_height=p.cam_height, tilt_deg=p.tilt_deg,
                                             vibration=p.vibration, start_offset=p.start_offset_m)
        self.light = light_schedule(n, p.light_start, p.light_end, p.light_ramp)
        self.renderer = Renderer(self.scene, self.calibration, max_range=p.max_range)
        self.conditions = Conditions(self.calibration, self.scene, self.seed)
        self.T_cam0_cam1 = np.eye(4)
        self.T_cam0_cam1[0, 3] = self.calibration.baseline

    def __len__(self) -> int:
        return self.n_frames

    def render_clean(self, i: int, cam: int = 0) -> RenderOutput:
        """Noise-free render of frame ``i`` for camera 0 (left) or 1 (right)."""
        T = self.track.poses[i] if cam == 0 else self.track.poses[i] @ self.T_cam0_cam1
        return self.renderer.render(T)

    def image(self, out: RenderOutput, i: int, cam: int) -> np.ndarray:
        """Final 8-bit image of a render under frame ``i``'s conditions (noise seeded per frame and camera)."""
        p = self.params
        rng = np.random.default_rng([self.seed, 0x1A6E, i, cam])
        return self.conditions.apply(
            out, rng, light=float(self.light[i]), haze_beta=p.haze_beta, airlight=p.airlight,
            shade_strength=p.shade_strength, gain=p.gain, noise=p.noise, full_well=p.full_well,
            read_noise_e=p.read_noise_e, low_texture_contrast=p.low_texture_contrast)

    def stereo(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(left uint8, right uint8, left depth float32 metres with inf for sky) of frame ``i``."""
        left = self.render_clean(i, 0)
        right = self.render_clean(i, 1)
        return self.image(left, i, 0), self.image(right, i, 1), left.depth


# -- files ------------------------------------------------------------------------

def _sensor_yaml(cal, T_BS: np.ndarray, rate_hz: float, comment: str) -> str:
    data = ", ".join(f"{v:.10g}" for v in T_BS.ravel())
    return (
        "%YAML:1.0\n"
        "# Canopy SLAM generated orchard sequence (canopy.synthetic). Rectified pinhole,\n"
        "# no distortion; body frame = cam0, so cam0's T_BS is the identity.\n"
        "sensor_type: camera\n"
        f"comment: {comment}\n\n"
        "T_BS:\n  cols: 4\n  rows: 4\n"
        f"  data: [{data}]\n\n"
        f"rate_hz: {rate_hz:g}\n"
        f"resolution: [{cal.width}, {cal.height}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{cal.fx:.10g}, {cal.fy:.10g}, {cal.cx:.10g}, {cal.cy:.10g}] #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )


def _quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), w >= 0, of rotation matrices (N, 3, 3)."""
    q = np.empty((len(R), 4))
    for k, m in enumerate(R):
        tr = np.trace(m)
        if tr > 0:
            s = 2.0 * np.sqrt(tr + 1.0)
            q[k] = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        else:
            i = int(np.argmax(np.diag(m)))
            j, kk = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[kk, kk])
            v = np.empty(3)
            v[i] = 0.25 * s
            v[j] = (m[j, i] + m[i, j]) / s
            v[kk] = (m[kk, i] + m[i, kk]) / s
            q[k] = [(m[kk, j] - m[j, kk]) / s, *v]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    return q


def groundtruth_csv(track: CameraTrack) -> str:
    """EuRoC state_groundtruth_estimate0 CSV (velocity by central differences, zero biases)."""
    p = track.poses[:, :3, 3]
    q = _quat_wxyz(track.poses[:, :3, :3])
    v = np.gradient(p, track.stamps - track.stamps[0], axis=0) if len(p) > 1 else np.zeros_like(p)
    lines = ["#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
             "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x [rad s^-1], "
             "b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], "
             "b_a_RS_S_z [m s^-2]"]
    for k, st in enumerate(track.stamps_ns.tolist()):
        vals = [*p[k], *q[k], *v[k]]
        lines.append(f"{st}," + ",".join(f"{x:.12g}" for x in vals) + ",0,0,0,0,0,0")
    return "\n".join(lines) + "\n"


def _image_list_csv(stamps_ns: np.ndarray) -> str:
    return "#timestamp [ns],filename\n" + "".join(f"{s},{s}.png\n" for s in stamps_ns.tolist())


def depth_to_png(depth: np.ndarray) -> np.ndarray:
    """Metres (inf = sky) -> uint16 millimetres, 0 where there is no surface or it is beyond 65.5 m."""
    mm = np.rint(np.where(np.isfinite(depth), depth, 0.0) * DEPTH_SCALE)
    return np.where((mm > 0) & (mm <= 65535), mm, 0).astype(np.uint16)


# -- workers ------------------------------------------------------------------------

_WORKER: SequenceGenerator | None = None


def _init_worker(params: SyntheticParams, seed: int) -> None:
    global _WORKER
    cv2.setNumThreads(1)
    _WORKER = SequenceGenerator(params, seed)


def _write_frames(mav0: Path, gen: SequenceGenerator, indices: list[int]) -> int:
    stamps = gen.track.stamps_ns
    for i in indices:
        left, right, depth = gen.stereo(i)
        name = f"{stamps[i]}.png"
        cv2.imwrite(str(mav0 / "cam0" / "data" / name), left, PNG_FAST)
        cv2.imwrite(str(mav0 / "cam1" / "data" / name), right, PNG_FAST)
        if gen.params.write_depth:
            cv2.imwrite(str(mav0 / "depth0" / "data" / name), depth_to_png(depth), PNG_FAST)
    return len(indices)


def _worker_chunk(mav0: str, indices: list[int]) -> int:
    assert _WORKER is not None
    return _write_frames(Path(mav0), _WORKER, indices)


def _stamp(preset: str, seed: int, params: SyntheticParams) -> dict:
    return {"generator": GENERATOR, "version": VERSION, "preset": preset, "seed": int(seed),
            "params": json.loads(json.dumps(asdict(params)))}


def _is_complete(out: Path, stamp: dict) -> bool:
    f = out / STAMP_FILE
    if not f.is_file():
        return False
    try:
        saved = json.loads(f.read_text())
    except (OSError, ValueError):
        return False
    if {k: saved.get(k) for k in stamp} != stamp:
        return False
    n = saved.get("n_frames", -1)
    mav0 = out / "mav0"
    return all(len(list((mav0 / c / "data").glob("*.png"))) == n for c in ("cam0", "cam1"))


def generate_sequence(preset: str, out_dir: str | Path, n_frames: int | None = None, seed: int = 0,
                      *, workers: int | None = None, progress: Callable[[int, int], None] | None = None,
                      **overrides) -> Path:
    """Generate (or reuse a cached copy of) a synthetic orchard sequence.

    preset: a key of ``PRESETS``; n_frames: None = the preset's length;
    overrides: any ``SyntheticParams`` field (e.g. ``haze_beta=0.2``,
    ``camera="kitti"``, ``noise=False``). Returns ``out_dir``, which
    ``open_source("euroc", out_dir)`` reads. If ``out_dir`` already holds a
    complete sequence with the same preset, seed and parameters, nothing is
    rendered. ``workers``: render processes (default: up to 2).
    """
    params = resolve_params(preset, n_frames, **overrides)
    out = Path(out_dir)
    stamp = _stamp(preset, seed, params)
    if _is_complete(out, stamp):
        return out
    # Two processes asking for the same sequence (a benchmark and a launch, say) must not both
    # render into one folder: the second would take the first's half-written folder for a stale
    # one and delete it. The second waits for the first and then reuses its output.
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f".{out.name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if _is_complete(out, stamp):
            return out
        return _render_sequence(params, seed, stamp, out, workers, progress)


def _render_sequence(params: SyntheticParams, seed: int, stamp: dict, out: Path, workers: int | None,
                     progress: Callable[[int, int], None] | None) -> Path:
    """Render every frame of ``params`` into ``out`` (called with the folder's lock held)."""
    if out.exists():
        if not out.is_dir():
            raise InputError(out, "output path exists and is not a folder")
        ours = (out / STAMP_FILE).is_file() or (out / PARTIAL_FILE).is_file()
        if any(out.iterdir()) and not ours:
            raise InputError(out, "folder is not empty and holds no generated sequence (no params.json); "
                                  "refusing to overwrite it")
        (out / STAMP_FILE).unlink(missing_ok=True)
        shutil.rmtree(out / "mav0", ignore_errors=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / PARTIAL_FILE).write_text(json.dumps(stamp) + "\n")

    gen = SequenceGenerator(params, seed)
    n = len(gen)
    mav0 = out / "mav0"
    cal = gen.calibration
    T_B_c1 = np.eye(4)
    T_B_c1[0, 3] = cal.baseline
    folders = {"cam0": np.eye(4), "cam1": T_B_c1}
    if params.write_depth:
        folders["depth0"] = np.eye(4)
    for name, T in folders.items():
        (mav0 / name / "data").mkdir(parents=True, exist_ok=True)
        comment = {"cam0": "left camera", "cam1": "right camera",
                   "depth0": "exact depth of cam0 as uint16 PNG, millimetres (depth_scale 1000), 0 = sky"}[name]
        text = _sensor_yaml(cal, T, params.rate_hz, comment)
        if name == "depth0":
            text += f"depth_scale: {DEPTH_SCALE:g}\n"
        (mav0 / name / "sensor.yaml").write_text(text)
        (mav0 / name / "data.csv").write_text(_image_list_csv(gen.track.stamps_ns))
    (mav0 / "state_groundtruth_estimate0").mkdir(parents=True, exist_ok=True)
    (mav0 / "state_groundtruth_estimate0" / "data.csv").write_text(groundtruth_csv(gen.track))

    workers = workers if workers is not None else min(2, os.cpu_count() or 1)
    chunk = 16
    chunks = [list(range(a, min(a + chunk, n))) for a in range(0, n, chunk)]
    done = 0
    if workers <= 1 or n < 2 * chunk:
        for c in chunks:
            done += _write_frames(mav0, gen, c)
            if progress:
                progress(done, n)
    else:
        # spawn, not fork: the caller may hold threads (ZeroMQ, OpenCV) that fork would copy half-alive.
        try:
            with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=_init_worker,
                                     initargs=(params, seed)) as pool:
                for k in pool.map(_worker_chunk, [str(mav0)] * len(chunks), chunks):
                    done += k
                    if progress:
                        progress(done, n)
        except BrokenProcessPool:
            # Workers could not start (e.g. a __main__ read from stdin cannot be re-imported):
            # render in this process instead; frames are deterministic either way.
            done = 0
            for c in chunks:
                done += _write_frames(mav0, gen, c)
                if progress:
                    progress(done, n)

    stamp["n_frames"] = n
    stamp["calibration"] = cal.to_dict()
    stamp["path_length_m"] = float(np.linalg.norm(np.diff(gen.track.poses[:, :3, 3], axis=0), axis=1).sum())
    tmp = out / (STAMP_FILE + ".tmp")
    tmp.write_text(json.dumps(stamp, indent=2) + "\n")
    tmp.replace(out / STAMP_FILE)
    (out / PARTIAL_FILE).unlink(missing_ok=True)
    return out
