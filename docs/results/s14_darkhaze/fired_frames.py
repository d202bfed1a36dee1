#!/usr/bin/env python
"""s14-darkhaze: the frames where tracking.ransac_max_deviation_deg fires, with the frame-to-frame rotation
error against ground truth there, the rule on and off (diag_frames.py's per-frame loop; the frames
before the first firing are identical, later ones carry their own history). Run:

    CANOPY_CACHE_DIR=/work/cache PYTHONPATH=$PWD python docs/results/s14_darkhaze/fired_frames.py \
        /work/cache/degraded/kitti-all-g0.06-b0.06-low-seed0 [...]
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
HOOK = """
import sys, runpy
import numpy as np
import canopy.frontend.motion_check as mc
import canopy.frontend.track_health as th
import canopy.frontend.tracker as trk
FIRED = {}
cur = {}
_r = trk.Tracker._ransac
def ransac(self, fi, X, uv):
    cur['f'] = fi
    return _r(self, fi, X, uv)
trk.Tracker._ransac = ransac
_d = mc.ransac_departs
def dep(T, Tp, p):
    out = _d(T, Tp, p)
    if out:
        FIRED[cur['f']] = round(th.motion_deviation(T, Tp)[1], 2)
    return out
mc.ransac_departs = dep
sys.argv = ["diag", *sys.argv[1:]]
try:
    runpy.run_path(%r, run_name="__main__")
finally:
    open(%r, "w").write(__import__("json").dumps(FIRED))
"""


def run(path: str, on: bool, tmp: Path) -> tuple[dict, list, float]:
    out, fired = tmp / f"{on}.npz", tmp / f"{on}.json"
    code = HOOK % (str(HERE.parent / "s13_haze" / "diag_frames.py"), str(fired))
    sets = [] if on else ["--set", "tracking.ransac_max_deviation_deg=0"]
    res = subprocess.run([sys.executable, "-c", code, path, "--quiet", "--out", str(out), *sets],
                         capture_output=True, text=True, check=True)
    import numpy as np
    rows = json.loads(str(np.load(out)["rows"]))
    ate = json.loads(res.stdout[res.stdout.index("{"):])["ate_mm"]
    return {int(k): v for k, v in json.loads(fired.read_text()).items()}, rows, ate


def main() -> int:
    for path in sys.argv[1:]:
        with tempfile.TemporaryDirectory() as t:
            fired, on_rows, ate_on = run(path, True, Path(t))
            _, off_rows, ate_off = run(path, False, Path(t))
        first = min(fired) if fired else None
        parts = [f"f{i} dev {d:.2f}: drot {off_rows[i].get('drot', float('nan')):.2f} -> {on_rows[i].get('drot', float('nan')):.2f}"
                 + (" (first)" if i == first else "") for i, d in sorted(fired.items())]
        print(f"{Path(path).name}: ATE {ate_off:.1f} -> {ate_on:.1f} mm; fired {len(fired)}: " + "; ".join(parts), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
