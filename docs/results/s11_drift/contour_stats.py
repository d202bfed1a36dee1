# One in-process run of a preset cell (the grid's runner, benchmarks/bench_enhance_diagnose.run, method
# auto) with the contour test's per-frame statistics recorded: stereo points tested, flagged, flagged
# because StereoBM found no match near them (lo == 0) vs a disparity step, and the fraction of the
# image StereoBM matched at all (columns: tested, flagged after the frame gate, flagged for 'unmatched
# near' before it, matched fraction, mean left grey level, flagged before the gate). Saves them with the per-frame rows and poses to an npz.
# Usage: contour_stats.py CELL|PRESET-clean[-N] OUT.npz [section.field=value ...]
import sys
import numpy as np
import benchmarks.bench_enhance_diagnose as bd
import canopy.frontend.stereo_silhouette as ss
from canopy.config import parse_value

cell, out_path, sets = sys.argv[1], sys.argv[2], sys.argv[3:]
track = {k.split(".", 1)[1]: parse_value(v) for k, v in (s.split("=", 1) for s in sets)}
stats = []
orig_call, orig_disp = ss.SilhouetteDetector.__call__, ss.SilhouetteDetector.disparity


def disparity(self, left, right):
    self._last = orig_disp(self, left, right) + (float(np.mean(left)),)
    return self._last[:2]


def call(self, left, right, uv, octave=None, scale_factor=1.2):
    on = orig_call(self, left, right, uv, octave, scale_factor)  # with the frame gate, if set
    d, first, mean = self._last
    s = self.params.downscale
    h, w = d.shape
    x = np.clip(np.round(uv[:, 0] / s).astype(np.int64), 0, w - 1)
    y = np.clip(np.round(uv[:, 1] / s).astype(np.int64), 0, h - 1)
    _, lo = self._min_max(d, self.radius)
    raw = self.flags(d, first, uv, octave, scale_factor)  # before the gate
    unmatched = (lo[y, x] <= 0) & raw
    stats.append((len(uv), int(on.sum()), int(unmatched.sum()), self.matched_fraction(d, first), mean, int(raw.sum())))
    return on


ss.SilhouetteDetector.disparity = disparity
ss.SilhouetteDetector.__call__ = call
captured = {}
orig_ape = bd.ape


def ape(est, gt, align="se3"):
    captured.setdefault("est", est); captured.setdefault("gt", gt)
    return orig_ape(est, gt, align)


bd.ape = ape
preset = cell.split("-")[0] + "-" + cell.split("-")[1]
if "-clean" in cell:
    path, n = f"/work/cache/synthetic/{preset}-seed0-full", (int(cell.split("-")[3]) if cell.count("-") == 3 else None)
else:
    path, n = f"/work/cache/degraded/{cell}", int(cell.split("-")[2])
out, rows = bd.run(path, f"/work/cache/synthetic/{preset}-seed0-full", "synthetic",
                   {"method": "auto"}, track, n, stereo=False, kind="euroc")
st = np.array(stats, float).reshape(-1, 6)
np.savez(out_path, est=captured.get("est"), gt=captured.get("gt"), stats=st,
         status=np.array([r["status"] for r in rows]),
         inl=np.array([float(r["inl"]) for r in rows]), matches=np.array([float(r["matches"]) for r in rows]))
print(out)
if len(st):
    print("gated frames %d; raw flagged %.1f %%" % (int(((st[:, 5] > 0) & (st[:, 1] == 0)).sum()), 100 * st[:, 5].sum() / st[:, 0].sum()))
    print("frames tested %d; stereo pts median %.0f; flagged %.1f %% (unmatched-near %.1f %%); BM matched %.2f; "
          "flagged frac p90 %.2f" % (len(st), np.median(st[:, 0]), 100 * st[:, 1].sum() / st[:, 0].sum(),
                                      100 * st[:, 2].sum() / st[:, 0].sum(), np.median(st[:, 3]),
                                      np.percentile(st[:, 1] / np.maximum(st[:, 0], 1), 90)))
