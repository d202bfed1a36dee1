"""EuRoC verdicts of grid runs against main's grid (docs/results/bench_degrade_grid.json) and ORB-SLAM3 raw.

python docs/results/s13_euroc/compare.py RUN.json [RUN2.json ...]   (docs/notes/s13-euroc.md)
Rows of later files override earlier ones; clean from the runs (else main's). Issue 9's checks:
bar = auto tracks 100 % and ATE <= 1.5 x clean (cells where ORB-SLAM3 raw tracks >= half);
'>= ORB' = tracked % and ATE at least as good as ORB-SLAM3 raw (the grid's median run)."""
import json, sys
main = json.load(open("docs/results/bench_degrade_grid.json"))["rows"]
ORB_SEED1 = {"g1-b0-low": 0.0009344, "g1-b0.06-low": 0.0007636}  # s11-noise, 3 runs each, all equal
ORB_EXTRA = json.loads(open(sys.argv[1] + ".orb").read()) if False else {}


def key(r):
    return r["cell"]


old = {key(r): r for r in main if r["dataset"] == "euroc" and r["method"] == "auto"}
orb = {key(r): r for r in main if r["dataset"] == "euroc" and r["method"] == "orbslam3-raw"}
new = {}
for f in sys.argv[1:]:
    for r in json.load(open(f))["rows"]:
        if r["dataset"] == "euroc" and r["method"] == "auto":
            new[key(r)] = r
        if r["dataset"] == "euroc" and r["method"] == "orbslam3-raw":
            orb[key(r)] = r
clean_new = (new.get("clean") or old["clean"])["ate_rmse_m"]
clean_old = old["clean"]["ate_rmse_m"]
print(f"clean {clean_old * 1e3:.4f} -> {clean_new * 1e3:.4f} mm; bar {1.5 * clean_old * 1e3:.3f} -> {1.5 * clean_new * 1e3:.3f}")
fmt = lambda r: "—" if r is None else (f"{r['ate_rmse_m'] * 1e3:.3f}" if r.get("tracked_pct", 0) >= 100 - 1e-9 and r.get("ate_rmse_m")
                                       else f"{r.get('tracked_pct', 0):.0f}% {(r.get('ate_rmse_m') or 0) * 1e3:.3f}")


def verdict(r, o, clean):
    if r is None:
        return "", ""
    half = o is not None and o["tracked_pct"] >= 50
    ok = r["tracked_pct"] >= 100 - 1e-9 and r["ate_rmse_m"] is not None
    bar = ("pass" if ok and r["ate_rmse_m"] <= 1.5 * clean else "FAIL") if half else "n/a"
    if o is None or not o["tracked_pct"]:
        ge = "pass" if r["tracked_pct"] >= (o or {"tracked_pct": 0})["tracked_pct"] else "FAIL"
    else:
        t_ok = r["tracked_pct"] >= o["tracked_pct"] - 1e-9
        a_ok = r["ate_rmse_m"] is not None and o["ate_rmse_m"] is not None and r["ate_rmse_m"] <= o["ate_rmse_m"]
        ge = "pass" if t_ok and a_ok else "FAIL"
    return bar, ge


print(f"{'cell':18s} {'main':>8s} {'new':>8s} {'ORB raw':>8s}  bar old->new   >=ORB old->new")
for c in sorted(set(old) | set(new), key=lambda c: (c != "clean", c)):
    o = orb.get(c)
    bo, go = verdict(old.get(c), o, clean_old)
    bn, gn = verdict(new.get(c), o, clean_new)
    print(f"{c:18s} {fmt(old.get(c)):>8s} {fmt(new.get(c)):>8s} {fmt(o):>8s}  {bo:>4s} -> {bn:4s}  {go:>4s} -> {gn:4s}")
