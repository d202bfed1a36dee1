"""The bad-input corpus (issue 11): every case ends with one clear line naming the input and
exit code 2, before any process starts, never a traceback; inputs that can be used but not as
given (colour or 16-bit images, files without a stereo twin) run with a warning.

Most cases call ``launch.main`` in-process: they must fail before any actor starts, so they cost
milliseconds. One case runs the real launcher on a 3-frame folder to show warnings end to end.
"""
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import zmq

import launch
from canopy.sources import open_source
from shared.errors import InputWarning

ROOT = Path(__file__).resolve().parents[1]
KITTI = ROOT / "data" / "kitti06_snippet"
EUROC = ROOT / "data" / "euroc_v101_micro"


def _run(argv, capsys) -> tuple[int, str]:
    """launch.main in-process; returns (exit code, stderr)."""
    code = launch.main(argv)
    err = capsys.readouterr().err
    return code, err


def _kitti_copy(tmp_path: Path, n: int = 4, name: str = "kitti") -> Path:
    dst = tmp_path / name
    for sub in ("image_l", "image_r"):
        (dst / sub).mkdir(parents=True)
        for i in range(n):
            shutil.copy(KITTI / sub / f"{i:06d}.png", dst / sub)
    shutil.copy(KITTI / "calib.txt", dst)
    shutil.copy(KITTI / "times.txt", dst)
    return dst


def _folder_dataset(tmp_path: Path, n: int = 3, convert=None, extra_left: int = 0) -> Path:
    """A plain stereo folder from the KITTI snippet; ``convert`` maps each grey image to what is
    stored (e.g. 16-bit colour)."""
    dst = tmp_path / "folder"
    for side, sub in (("left", "image_l"), ("right", "image_r")):
        (dst / side).mkdir(parents=True)
        for i in range(n + (extra_left if side == "left" else 0)):
            img = cv2.imread(str(KITTI / sub / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
            cv2.imwrite(str(dst / side / f"{i:06d}.png"), convert(img) if convert else img)
    (dst / "calib.yaml").write_text("fx: 707.0912\nfy: 707.0912\ncx: 601.8873\ncy: 183.1104\n"
                                    "baseline: 0.537\nrate_hz: 10\n")
    return dst


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- cases that must end before any process starts ------------------------------------------------

def _out_is_file(tmp):
    f = tmp / "results.txt"
    f.write_text("x")
    return ["--out", str(f)], "is a file, not a folder"


def _out_under_file(tmp):
    f = tmp / "results.txt"
    f.write_text("x")
    return ["--out", str(f / "run")], "a parent is a file"


def _out_cannot_be_created(tmp):
    return ["--out", "/sys/canopy-results/run"], "cannot create the folder"  # sysfs: EPERM even for root


def _out_not_writable(tmp):
    return ["--out", "/proc/1"], "not writable"  # exists, is a folder, takes no files (even for root)


def _config(tmp, text):
    cfg = tmp / "bad.yaml"
    cfg.write_text(text)
    return ["--config", str(cfg)]


def _section_is_list(tmp):
    return _config(tmp, "tracking: [1, 2]\n"), "section 'tracking' must be a mapping"


def _heartbeat_zero(tmp):
    return _config(tmp, "runtime:\n  heartbeat_timeout_s: 0\n"), "runtime.heartbeat_timeout_s: must be at least"


def _grace_negative(tmp):
    return _config(tmp, "runtime:\n  grace_s: -1\n"), "runtime.grace_s"


def _ring_slots_huge(tmp):
    return _config(tmp, "runtime:\n  ring_slots: 100000\n"), "runtime.ring_slots"


def _wait_nan(tmp):
    return _config(tmp, "runtime:\n  lockstep_wait_s: .nan\n"), "runtime.lockstep_wait_s"


def _prefetch_overruns_ring(tmp):  # the source would overwrite a slot tracking has not read yet
    return (_config(tmp, "runtime:\n  ring_slots: 4\n  lockstep_prefetch_frames: 3\n"),
            "runtime.lockstep_prefetch_frames: must be 0..ring_slots - 2 (2), got 3")


def _inspect_malformed(tmp):
    return ["--inspect", "tcp://localhost"], "expected tcp://HOST:PORT"


def _inspect_bad_scheme(tmp):
    return ["--inspect", "http://localhost:80"], "expected tcp://HOST:PORT or ipc://PATH"


def _inspect_unknown_host(tmp):
    return ["--inspect", "tcp://no-such-host.invalid:5560"], "unknown host 'no-such-host.invalid'"


def _inspect_port_in_use(tmp):
    port = _free_port()
    holder = zmq.Context.instance().socket(zmq.PUB)
    holder.bind(f"tcp://127.0.0.1:{port}")
    tmp.joinpath("holder").write_text("")  # keep the socket alive through the fixture
    _HOLD.append(holder)
    return ["--inspect", f"tcp://127.0.0.1:{port}"], "cannot listen on"


_HOLD: list = []


def _inspect_public_without_keys(tmp):
    return ["--inspect", f"tcp://0.0.0.0:{_free_port()}"], "a non-loopback address needs CURVE keys"


def _inspect_keys_folder_empty(tmp):
    return ["--inspect", f"tcp://0.0.0.0:{_free_port()}", "--inspect-keys", str(tmp)], "no server.key_secret"


def _tiny_images(tmp):
    path = _folder_dataset(tmp, n=2, convert=lambda img: img[:1, :1])
    return ["--dataset", "folder", "--path", str(path)], "at least 64x64 pixels"


def _kitti_nan_focal(tmp):
    path = _kitti_copy(tmp, n=2)
    lines = (path / "calib.txt").read_text().splitlines()
    lines[0] = "nan" + lines[0][lines[0].index(" "):]
    (path / "calib.txt").write_text("\n".join(lines) + "\n")
    return ["--dataset", "kitti", "--path", str(path)], "field 'P0' number 1 of 12 is not finite (nan)"


def _euroc_nan_intrinsics(tmp):
    path = tmp / "euroc"
    shutil.copytree(EUROC, path, ignore=shutil.ignore_patterns("imu0"))
    yml = path / "mav0" / "cam0" / "sensor.yaml"
    text = yml.read_text()
    start = text.index("intrinsics:")
    yml.write_text(text[:start] + "intrinsics: [458.654, .nan, 367.215, 248.375]" + text[text.index("\n", start):])
    return ["--dataset", "euroc", "--path", str(path)], "field 'intrinsics': number 2 of 4 is not finite"


def _euroc_listed_image_missing(tmp):
    path = tmp / "euroc"
    shutil.copytree(EUROC, path, ignore=shutil.ignore_patterns("imu0"))
    victim = sorted((path / "mav0" / "cam0" / "data").glob("*.png"))[7]
    victim.unlink()
    return ["--dataset", "euroc", "--path", str(path)], f"{victim.name}: image listed in cam0/data.csv"


def _zero_byte_first_image(tmp):
    path = _kitti_copy(tmp, n=3)
    (path / "image_r" / "000000.png").write_bytes(b"")
    return ["--dataset", "kitti", "--path", str(path)], "000000.png: cannot decode image"


def _mismatched_pair(tmp):
    path = _kitti_copy(tmp, n=3)
    small = cv2.imread(str(path / "image_r" / "000000.png"), cv2.IMREAD_GRAYSCALE)[::2, ::2]
    cv2.imwrite(str(path / "image_r" / "000000.png"), small)
    return ["--dataset", "kitti", "--path", str(path)], "right image is 613x185"


def _max_frames_zero(tmp):
    return ["--max-frames", "0"], "--max-frames must be at least 1"


def _missing_dataset(tmp):
    return ["--dataset", "kitti", "--path", str(tmp / "nowhere")], "nowhere: KITTI sequence folder not found"


CASES = [_out_is_file, _out_under_file, _out_cannot_be_created, _out_not_writable, _section_is_list,
         _heartbeat_zero, _grace_negative, _ring_slots_huge, _wait_nan, _prefetch_overruns_ring, _inspect_malformed, _inspect_bad_scheme,
         _inspect_unknown_host, _inspect_port_in_use, _inspect_public_without_keys, _inspect_keys_folder_empty, _tiny_images, _kitti_nan_focal, _euroc_nan_intrinsics,
         _euroc_listed_image_missing, _zero_byte_first_image, _mismatched_pair, _max_frames_zero,
         _missing_dataset]


@pytest.mark.parametrize("case", CASES, ids=[c.__name__.strip("_") for c in CASES])
def test_bad_input_ends_with_one_clear_line_before_any_process(case, tmp_path, capsys, monkeypatch):
    started = []
    monkeypatch.setattr("actors.supervisor.Supervisor.run", lambda self: started.append(1))
    argv, fragment = case(tmp_path)
    try:
        code, err = _run([*argv, "--quiet"], capsys)
    finally:
        for sock in _HOLD:
            sock.close(linger=0)
        _HOLD.clear()
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert code == 2, err
    assert len(lines) == 1 and fragment in lines[0], err
    assert not started, "an actor process was started for bad input"


# -- usable input: a warning, then the run ------------------------------------------------------

def test_unmatched_kitti_images_warn_and_are_skipped(tmp_path):
    path = _kitti_copy(tmp_path, n=6)
    for i in (4, 5):
        (path / "image_r" / f"{i:06d}.png").unlink()
    with pytest.warns(InputWarning, match=r"image_l: 2 image\(s\) have no twin in image_r/.*000004.png"):
        src = open_source("kitti", path)
    assert len(src) == 4


def test_euroc_stamps_listed_by_one_camera_warn(tmp_path):
    # the bundled micro set itself: cam1/data.csv lists 4 stamps cam0 does not
    with pytest.warns(InputWarning, match=r"cam1/data.csv: 4 stamp\(s\) have no image listed by cam0"):
        src = open_source("euroc", EUROC)
    assert len(src) == 95


def test_converted_images_warn_and_run(tmp_path):
    """16-bit colour PNGs and a left image without a right twin: two warnings, then a normal run."""
    path = _folder_dataset(tmp_path, n=3, extra_left=1,
                           convert=lambda img: cv2.cvtColor(img, cv2.COLOR_GRAY2BGR).astype(np.uint16) * 257)
    out = tmp_path / "run"
    res = subprocess.run([sys.executable, str(ROOT / "launch.py"), "--dataset", "folder", "--path", str(path),
                          "--out", str(out), "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    warnings = [ln for ln in res.stderr.splitlines() if ln.startswith("warning:")]
    assert any("3-channel colour converted to grey" in w and "uint16 pixels scaled to 8 bit" in w
               for w in warnings), res.stderr
    assert any("left: 1 image(s) have no twin in right/" in w for w in warnings), res.stderr
    assert "Traceback" not in res.stderr
    assert len(np.loadtxt(out / "trajectory.tum")) == 3


def test_colour_images_read_as_the_same_grey(tmp_path):
    """The conversion the warning announces is the plain one: 8-bit grey equals the original."""
    path = _folder_dataset(tmp_path, n=1, convert=lambda img: cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    with pytest.warns(InputWarning):
        frame = open_source("folder", path).frame(0)
    orig = cv2.imread(str(KITTI / "image_l" / "000000.png"), cv2.IMREAD_GRAYSCALE)
    assert np.abs(frame.left.astype(int) - orig).max() <= 1
