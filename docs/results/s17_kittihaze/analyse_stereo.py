"""s17-kittihaze: read diag_stereo.py's npz: per-frame enhancer decisions, disparity errors against the
clean SGBM, and whether a disparity bound with various noise models ranks them.
Usage: analyse_stereo.py NPZ [SUBPIXEL_HALF_WINDOW]"""
import json
import sys
import numpy as np

z = np.load(sys.argv[1])
frames = json.loads(str(z["frames"]))
P = z["pts"]; n = int(z["n"])
i, u, v, oc, depth, d_est, d_ref, sxx, nxx, nvar, unc = P.T
print("frames: method / noise_sigma / gamma / eps / robust / est_enh / est_raw")
from collections import Counter
print(Counter(f["method"] for f in frames))
for k in ("noise_sigma", "gamma", "eps_factor", "robust", "est_enh", "est_raw"):
    vals = np.array([f[k] if f[k] is not None else np.nan for f in frames], float)
    print(f"  {k:12s} p10 {np.nanpercentile(vals,10):.2f} p50 {np.nanpercentile(vals,50):.2f} p90 {np.nanpercentile(vals,90):.2f}")
m = d_ref > 0
e = d_est - d_ref
print("points", len(P), "scored", m.sum(), "uncertain flagged (as run)", int(unc.sum()))
print("|dd| p50 %.2f  >1px %.0f%%  >3px %.0f%%  mean dd %.3f" % (np.median(np.abs(e[m])), 100*np.mean(np.abs(e[m]) > 1),
      100*np.mean(np.abs(e[m]) > 3), np.mean(np.clip(e[m], -5, 5))))
sig_meas = np.sqrt(np.maximum(nvar, 1e-9))   # the noise's std over the window (two-draw difference)
fs = {f["i"]: f for f in frames}
pre = np.array([fs[int(k)]["noise_sigma"] or fs[int(k)]["robust"] or 0 for k in i])
rob = np.array([fs[int(k)]["robust"] or fs[int(k)]["est_enh"] for k in i])
print("window noise std (two-draw) p10/50/90: %.2f %.2f %.2f; frame robust sigma p50 %.2f; pre-filter sigma p50 %.2f"
      % (*np.percentile(sig_meas, [10, 50, 90]), np.median(rob), np.median(pre)))
print("noise gradient energy nxx / (n sig^2/2) p10/50/90: %.2f %.2f %.2f" % tuple(np.percentile(nxx / (n * sig_meas**2 / 2), [10, 50, 90])))
sfac = 1.2 ** oc
def bound(sig, noise_energy):
    s = sxx - noise_energy
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(s > 0, np.sqrt(2 * sig**2 / np.maximum(s, 1e-9)), np.inf) * sfac
models = {
    "frame robust sigma (as run, white)": bound(rob, n * rob**2 / 2),
    "pre-filter sigma (white)": bound(pre, n * pre**2 / 2),
    "measured window noise (two-draw)": bound(sig_meas, nxx),
}
for name, sd in models.items():
    rel = sd / np.maximum(d_est, 1e-3)
    print(" by", name)
    qs = np.unique(np.percentile(rel[m], [0, 20, 40, 60, 80, 90, 95, 100]))
    for lo, hi in zip(qs[:-1], qs[1:]):
        mm = m & (rel >= lo) & (rel <= hi)
        ee = e[mm]
        if not len(ee):
            continue
        print("   %.4f-%.4f n %5d |dd| p50 %.2f >1px %3.0f%% >3px %3.0f%% rel-depth p50 %.3f z p50 %5.1f" % (
            lo, hi, mm.sum(), np.median(np.abs(ee)), 100*np.mean(np.abs(ee) > 1), 100*np.mean(np.abs(ee) > 3),
            np.median(np.abs(ee) / d_est[mm]), np.median(depth[mm])))
    for t in (0.05, 0.1, 0.2):
        print("     rel >= %.2f: %.1f%% of points, |dd| p50 %.2f vs %.2f below" % (t, 100*np.mean(rel[m] >= t),
              np.median(np.abs(e[m & (rel >= t)])) if (m & (rel >= t)).any() else np.nan, np.median(np.abs(e[m & (rel < t)]))))
# per frame disparity error summary
print("per frame: i method |dd|p50 >1px% bias(clip5) n")
for f in frames:
    mm = m & (i == f["i"])
    if mm.any():
        ee = e[mm]
        print("  %2d %-8s %.2f %3.0f %+.3f %4d" % (f["i"], f["method"], np.median(np.abs(ee)), 100*np.mean(np.abs(ee) > 1),
              np.mean(np.clip(ee, -5, 5)), mm.sum()))
