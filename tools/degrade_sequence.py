#!/usr/bin/env python
"""Write a darkened and/or hazy copy of a stereo sequence, in the same layout as the input.

    python tools/degrade_sequence.py --dataset kitti --out /tmp/kitti_dark --mode dark --gain 0.15
    python tools/degrade_sequence.py --dataset euroc --out /tmp/euroc_haze --mode haze --beta 0.3 --max-depth 20
    python tools/degrade_sequence.py --dataset kitti --out /tmp/kitti_grid --mode dark+haze --gain 0.06 --beta 0.06 --noise high
    python launch.py --dataset kitti --path /tmp/kitti_dark --enhance agri

Modes: ``dark`` (less light, with shot + read noise), ``haze``, ``dark+haze``,
``noise`` (the sensor noise at full light) and ``haze+noise``; ``--noise
low|high`` picks one of the degradation grid's sensors (``NOISE_LEVELS``:
full well and read noise) instead of ``--full-well`` / ``--read-noise``.

The physics lives in ``canopy.degrade``; this tool does the files.

KITTI (rectified images): ``calib.txt``, ``times.txt``, ``poses.txt`` and
every other non-image file at the top level are copied verbatim; the
degraded pairs go to folders with the input's names (``image_0``/``image_1``
or ``image_l``/``image_r``) under the input's file names. Haze depth (``--haze-depth
auto``): ``stereo-sky`` (``canopy.degrade.depth_for_haze``: 8-path SGBM on the clean
rectified pair kept where the image has texture, holes filled from the farthest
neighbour in row and column, sky far), one depth map per camera (the right one by
matching the mirrored pair); ``stereo`` is the old SGBM map (every disparity kept, holes
filled along rows), which paints far surfaces and sky too near (docs/notes/s22-hazepaint.md).

EuRoC (raw, distorted images): the whole folder is copied (``mav0`` with
``sensor.yaml``, ``imu0``, ground truth, and top-level notes) except the
camera PNGs, which are written degraded *as raw images*, so a reader
rectifies them exactly as it rectified the original. Haze depth (``--haze-depth
auto``, the default): a generated sequence's own rendered depth (``mav0/depth0``,
the left camera's, warped to the right one by its disparity), otherwise SGBM on the
clean pair as the source rectifies it; either is converted to ray length (unchanged by
rectification, which only rotates about the camera centre) and taken back to
every raw pixel: each raw pixel is undistorted and rotated into the
rectified image with ``cv2.undistortPoints`` (iterated to 1e-8) (the exact inverse of the
rectification map), and the ray length there is read with nearest-neighbour
lookup; raw pixels outside the rectified view (its ``alpha = 0`` crop) take
the nearest border value. Each camera's ``data.csv`` is rewritten to list
exactly the images written (the loader's stereo pairs, possibly truncated by
``--max-frames``).

Noise is seeded per frame and camera from ``--seed`` (same seed, same
files). A ``DEGRADED.yaml`` in the output folder records the parameters and
the input.
"""
from __future__ import annotations

import os
import sys

# Run as a script, Python puts tools/ first on sys.path; nothing there is a library.
if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(os.path.abspath(__file__)):
    sys.path.pop(0)

import argparse  # noqa: E402
import shutil  # noqa: E402
from dataclasses import asdict  # noqa: E402
from pathlib import Path  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from canopy.degrade import (DEGRADE_MODES, NOISE_LEVELS, DegradeParams, degrade_image,  # noqa: E402
                            depth_for_haze, depth_from_rendered, depth_from_stereo, ray_length)
from canopy.sources import BUNDLED_DATA, open_source  # noqa: E402
from canopy.sources.base import IMAGE_SUFFIXES, load_yaml_file, numbers  # noqa: E402
from canopy.sources.euroc import EurocSource  # noqa: E402
from canopy.sources.kitti import KittiSource  # noqa: E402
from shared.errors import CanopyError, ConfigError, InputError  # noqa: E402

# Accuracy of the raw -> rectified pixel inverse (iterative undistortPoints).
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-8)
# Largest grey-level difference tolerated between our re-derived rectification and the source's.
RECTIFY_CHECK_TOL = 1


def _frame_rng(seed: int, index: int, camera: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), int(index), int(camera)])


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):
        raise InputError(path, "cannot write image")


def _prepare_out(out: Path, src_root: Path, force: bool) -> None:
    out, src_root = out.resolve(), src_root.resolve()
    if out == src_root or src_root in out.parents or out in src_root.parents:
        raise ConfigError(str(out), f"output folder must not be the input folder {src_root} or contain/lie inside it")
    if out.exists() and any(out.iterdir()):
        if not force:
            raise ConfigError(str(out), "output folder exists and is not empty (use --force to replace it)")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)


def _ray_maps(left: np.ndarray, right: np.ndarray, calib, params: DegradeParams,
              haze_depth: str = "stereo") -> list[np.ndarray]:
    """Ray length (m) per rectified pixel, for the left and the right camera, from the clean pair's
    SGBM depth (``stereo``: ``depth_from_stereo``; ``stereo-sky``: ``depth_for_haze``)."""
    depth = depth_for_haze if haze_depth == "stereo-sky" else depth_from_stereo
    return [ray_length(depth(left, right, calib, params.max_depth, params.num_disparities,
                             params.block_size, view=v), calib) for v in ("left", "right")]


# -- KITTI --------------------------------------------------------------------------

def _degrade_kitti(src: KittiSource, out: Path, params: DegradeParams, log, haze_depth: str = "stereo-sky") -> int:
    root = src.root
    for p in root.iterdir():
        if p.is_file() and p.suffix.lower() not in IMAGE_SUFFIXES:
            shutil.copy2(p, out / p.name)
    left_dir, right_dir = src.left_paths[0].parent.name, src.right_paths[0].parent.name
    (out / left_dir).mkdir()
    (out / right_dir).mkdir()
    for i in range(len(src)):
        frame = src.frame(i)
        rays = _ray_maps(frame.left, frame.right, src.calibration, params, haze_depth) if params.haze else [None, None]
        for cam, (img, ray, path, folder) in enumerate(zip((frame.left, frame.right), rays,
                                                            (src.left_paths[i], src.right_paths[i]),
                                                            (left_dir, right_dir))):
            _write_png(out / folder / path.name, degrade_image(img, params, ray, _frame_rng(params.seed, i, cam)))
        log(i)
    return len(src)


# -- EuRoC --------------------------------------------------------------------------

class _RawToRectified:
    """For each raw pixel of one EuRoC camera, its (x, y) in that camera's rectified image."""

    def __init__(self, K, D, R, P, width: int, height: int):
        u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
        pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        rect = cv2.undistortPoints(pts, K, D, None, R, P, UNDISTORT_CRITERIA).reshape(height, width, 2)
        self.map_x = np.ascontiguousarray(rect[:, :, 0], dtype=np.float32)
        self.map_y = np.ascontiguousarray(rect[:, :, 1], dtype=np.float32)

    def pull(self, rectified_values: np.ndarray) -> np.ndarray:
        return cv2.remap(rectified_values, self.map_x, self.map_y, cv2.INTER_NEAREST,
                         borderMode=cv2.BORDER_REPLICATE)


def _euroc_rectification(src: EurocSource) -> tuple[list[_RawToRectified], list[tuple[np.ndarray, np.ndarray]]]:
    """Re-derive the source's rectification from sensor.yaml (same calls as ``EurocSource``).

    Returns the raw->rectified inverses and the forward maps, which the caller
    checks against the source's own rectified frame before trusting them.
    """
    mav0 = src.left_paths[0].parents[2]
    cams = []
    for c in ("cam0", "cam1"):
        path = mav0 / c / "sensor.yaml"
        data = load_yaml_file(path)
        fu, fv, cu, cv = numbers(data.get("intrinsics"), 4, path, "intrinsics")
        K = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
        D = numbers(data.get("distortion_coefficients"), None, path, "distortion_coefficients")
        t_bs = data.get("T_BS")
        T_B_S = numbers(t_bs.get("data") if isinstance(t_bs, dict) else t_bs, 16, path, "T_BS").reshape(4, 4)
        cams.append((K, D, T_B_S))
    (K0, D0, T0), (K1, D1, T1) = cams
    size = src.image_size
    T_c1_c0 = np.linalg.inv(np.linalg.inv(T0) @ T1)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K0, D0, K1, D1, size, T_c1_c0[:3, :3].copy(),
                                           T_c1_c0[:3, 3].reshape(3, 1).copy(),
                                           flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    inverses = [_RawToRectified(K, D, R, P, *size) for K, D, R, P in ((K0, D0, R1, P1), (K1, D1, R2, P2))]
    forward = [cv2.initUndistortRectifyMap(K, D, R, P, size, cv2.CV_16SC2)
               for K, D, R, P in ((K0, D0, R1, P1), (K1, D1, R2, P2))]
    return inverses, forward


def rectify_nearest(image: np.ndarray, forward) -> np.ndarray:
    """``image`` (raw camera) resampled into the rectified view by nearest neighbour, for values that
    must not blend (depth). The forward maps are converted to float first: OpenCV 5.0.0's nearest
    ``remap`` with fixed-point (CV_16SC2) maps shifted the result (on the generated presets, whose
    maps are the identity, 90 % of the depth pixels moved), so hazy cells painted with 5.0.0 and
    5.1.0 differed; float maps give the same exact lookup on every version (s23-lead note)."""
    map_x, map_y = cv2.convertMaps(*forward, cv2.CV_32FC1)
    return cv2.remap(image, map_x, map_y, cv2.INTER_NEAREST)


def _rendered_rays(depth_png: Path, forward_left, calib, params: DegradeParams) -> list[np.ndarray]:
    """Ray length per rectified pixel of both cameras from the renderer's left depth (uint16 mm,
    0 = sky), rectified as the source rectifies cam0 (nearest: depth must not blend across edges)."""
    raw = cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16:
        raise InputError(depth_png, "rendered depth: expected a uint16 PNG (mm)")
    z = rectify_nearest(raw, forward_left).astype(np.float64) / 1000.0
    return [ray_length(depth_from_rendered(z, calib, params.max_depth, view=v), calib) for v in ("left", "right")]


def _degrade_euroc(src: EurocSource, out: Path, params: DegradeParams, log, haze_depth: str = "stereo") -> int:
    src_root = src.root
    mav0_in = src.left_paths[0].parents[2]
    mav0_rel = mav0_in.relative_to(src_root) if mav0_in != src_root else Path(".")
    cam_dirs = ("cam0", "cam1")

    def ignore(folder, names):
        rel = Path(folder).resolve().relative_to(src_root.resolve())
        if rel.parent == mav0_rel and rel.name in cam_dirs:
            return ["data", "data.csv"]
        return []

    shutil.copytree(src_root, out, ignore=ignore, dirs_exist_ok=True)

    inverses = None
    depth_dir = mav0_in / "depth0" / "data"
    if params.haze:
        inverses, forward = _euroc_rectification(src)
        raw_l, raw_r = src.raw_pair(0)
        ref = src.frame(0)
        for (m1, m2), raw, rect in zip(forward, (raw_l, raw_r), (ref.left, ref.right)):
            diff = np.abs(cv2.remap(raw, m1, m2, cv2.INTER_LINEAR).astype(int) - rect.astype(int)).max()
            if diff > RECTIFY_CHECK_TOL:
                raise InputError(mav0_in, f"re-derived rectification differs from the source's by {diff} grey "
                                          "levels; cannot map haze depth back to the raw images")

    written: list[set[str]] = [set(), set()]
    for c in cam_dirs:
        (out / mav0_rel / c / "data").mkdir(parents=True, exist_ok=True)
    for i in range(len(src)):
        raw = src.raw_pair(i)
        rays = [None, None]
        if params.haze:
            if haze_depth == "rendered":
                maps = _rendered_rays(depth_dir / src.left_paths[i].name, forward[0], src.calibration, params)
            else:
                frame = src.frame(i)
                maps = _ray_maps(frame.left, frame.right, src.calibration, params, haze_depth)
            rays = [inv.pull(r) for inv, r in zip(inverses, maps)]
        for cam, path in enumerate((src.left_paths[i], src.right_paths[i])):
            img = degrade_image(raw[cam], params, rays[cam], _frame_rng(params.seed, i, cam))
            _write_png(out / mav0_rel / cam_dirs[cam] / "data" / path.name, img)
            written[cam].add(path.name)
        log(i)

    for cam, c in enumerate(cam_dirs):
        csv_in = mav0_in / c / "data.csv"
        lines = csv_in.read_text().splitlines()
        kept = [ln for ln in lines if not ln.strip() or ln.lstrip().startswith("#")
                or _csv_name(ln) in written[cam]]
        (out / mav0_rel / c / "data.csv").write_text("\n".join(kept) + "\n")
    return len(src)


def _csv_name(line: str) -> str:
    parts = [p.strip() for p in line.split(",")]
    return parts[1] if len(parts) > 1 and parts[1] else f"{parts[0]}.png"


# -- entry points ------------------------------------------------------------------------

HAZE_DEPTHS = ("auto", "stereo", "stereo-sky", "rendered")


def _depth_dir(src) -> Path:
    """Where a generated (EuRoC-layout) sequence keeps the renderer's left depth (uint16 mm PNGs)."""
    return src.left_paths[0].parents[2] / "depth0" / "data"


def _check_haze_depth(haze_depth: str, dataset: str) -> None:
    if dataset not in ("euroc", "kitti"):
        raise ConfigError("--dataset", f"must be euroc or kitti, got {dataset!r}")
    if haze_depth not in HAZE_DEPTHS:
        raise ConfigError("--haze-depth", f"must be one of {', '.join(HAZE_DEPTHS)}, got {haze_depth!r}")
    if haze_depth == "rendered" and dataset != "euroc":
        raise ConfigError("--haze-depth", f"'rendered' needs a generated (euroc-layout) sequence, got {dataset}")


def resolve_haze_depth(haze_depth: str, dataset: str, path: str | Path | None = None, src=None) -> str:
    """``stereo``, ``stereo-sky`` or ``rendered``: the depth the haze of ``dataset`` at ``path`` is made from.

    ``auto`` (the default) takes the renderer's exact depth where the sequence has it (generated
    sequences, ``mav0/depth0``) and SGBM on the clean pair otherwise (real data): ``stereo-sky``
    on KITTI (outdoor: textureless sky is far, ``depth_for_haze``), ``stereo`` on EuRoC (a hall: the
    top of the image is a ceiling, not sky; its recorded cells keep their haze). SGBM depth of a
    generated pair is blocky, has holes (painted as ``max_depth`` streaks) and differs between the
    two cameras, so the haze itself adds texture that is not in the scene (docs/notes/s8-haze.md,
    the dark-rows cell). ``stereo`` / ``rendered`` force one (``rendered`` on KITTI is an error)."""
    _check_haze_depth(haze_depth, dataset)
    if haze_depth != "auto":
        return haze_depth
    if dataset != "euroc":
        return "stereo-sky"
    src = src if src is not None else open_source(dataset, path, max_frames=1)
    return "rendered" if _depth_dir(src).is_dir() else "stereo"


def degrade_sequence(dataset: str, out: str | Path, params: DegradeParams, path: str | Path | None = None,
                     max_frames: int | None = None, force: bool = False, progress: bool = False,
                     haze_depth: str = "auto") -> Path:
    """Write the degraded copy of ``dataset`` at ``path`` (None: bundled) to ``out``; return ``out``.

    ``haze_depth``: ``auto`` (the renderer's depth where the sequence has it, else SGBM:
    ``resolve_haze_depth``), ``stereo`` (SGBM on the clean pair, any dataset), ``stereo-sky`` (SGBM
    kept where textured, sky far: ``canopy.degrade.depth_for_haze``) or ``rendered`` (the
    renderer's exact left depth, ``mav0/depth0`` of a generated sequence; needed where the clean pair
    is too dark for SGBM, e.g. dark-rows: docs/notes/s8-haze.md). DEGRADED.yaml records the one used."""
    _check_haze_depth(haze_depth, dataset)  # bad names fail before the source is opened
    src = open_source(dataset, path, max_frames=max_frames)
    haze_depth = resolve_haze_depth(haze_depth, dataset, src=src)
    depth_dir = _depth_dir(src) if dataset == "euroc" else None
    if params.haze and haze_depth == "rendered" and not depth_dir.is_dir():  # before anything is written
        raise InputError(depth_dir, "--haze-depth rendered needs the renderer's depth (mav0/depth0, generated sequences)")
    out = Path(out)
    _prepare_out(out, src.root, force)

    def log(i):
        if progress:
            print(f"\r{dataset}: frame {i + 1}/{len(src)}", end="", file=sys.stderr, flush=True)

    n = (_degrade_kitti(src, out, params, log, haze_depth) if dataset == "kitti"
         else _degrade_euroc(src, out, params, log, haze_depth))
    if progress:
        print(file=sys.stderr)
    record = {"input": str(src.root.resolve()), "dataset": dataset, "frames": n,
              "params": asdict(params), "tool": "tools/degrade_sequence.py", "model": "canopy.degrade"}
    if params.haze:
        record["haze_depth"] = haze_depth
    (out / "DEGRADED.yaml").write_text(yaml.safe_dump(record, sort_keys=False))
    return out


def main(argv=None) -> int:
    d = DegradeParams()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", required=True, choices=("euroc", "kitti"))
    ap.add_argument("--path", default=None, help="dataset folder (default: the bundled snippet: "
                    + ", ".join(f"{k}={v}" for k, v in BUNDLED_DATA.items()) + ")")
    ap.add_argument("--out", required=True, help="output folder (created; must not be the input)")
    ap.add_argument("--mode", default=d.mode, choices=DEGRADE_MODES)
    ap.add_argument("--gain", type=float, default=d.gain, help="light reaching the sensor (0.1 = 10x less)")
    ap.add_argument("--full-well", type=float, default=d.full_well, help="electrons at 8-bit white")
    ap.add_argument("--read-noise", type=float, default=d.read_noise, help="electrons rms")
    ap.add_argument("--noise", choices=tuple(NOISE_LEVELS), default=None,
                    help="a sensor of the degradation grid: " + ", ".join(
                        f"{k} = {fw:g} e- full well, {rn:g} e- read noise" for k, (fw, rn) in NOISE_LEVELS.items()))
    ap.add_argument("--gamma", type=float, default=d.gamma, help="encoding gamma of the images (1 = linear)")
    ap.add_argument("--beta", type=float, default=d.beta, help="haze extinction coefficient, 1/m")
    ap.add_argument("--airlight", type=float, default=d.airlight, help="airlight A, grey levels")
    ap.add_argument("--max-depth", type=float, default=d.max_depth, help="depth (m) for pixels without disparity")
    ap.add_argument("--num-disparities", type=int, default=d.num_disparities)
    ap.add_argument("--block-size", type=int, default=d.block_size)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--haze-depth", choices=HAZE_DEPTHS, default="auto",
                    help="haze depth: the renderer's depth where the sequence has it (generated sequences), "
                         "else SGBM on the clean pair (auto, default: stereo-sky on KITTI, stereo on EuRoC); "
                         "or force one: stereo (SGBM, every disparity), stereo-sky (textured SGBM, sky far), "
                         "rendered")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--force", action="store_true", help="replace a non-empty output folder")
    args = ap.parse_args(argv)
    if args.noise is not None:
        args.full_well, args.read_noise = NOISE_LEVELS[args.noise]
    try:
        params = DegradeParams(mode=args.mode, gain=args.gain, full_well=args.full_well,
                               read_noise=args.read_noise, gamma=args.gamma, beta=args.beta,
                               airlight=args.airlight, max_depth=args.max_depth,
                               num_disparities=args.num_disparities, block_size=args.block_size, seed=args.seed)
        out = degrade_sequence(args.dataset, args.out, params, path=args.path, max_frames=args.max_frames,
                               force=args.force, progress=True, haze_depth=args.haze_depth)
    except CanopyError as exc:
        print(f"degrade_sequence: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
