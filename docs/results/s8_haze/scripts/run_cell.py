import sys, json
from pathlib import Path
sys.path.insert(0, "/work/wt/s8-haze2")
from benchmarks.bench_degrade_grid import run_canopy_in_process, run_peer, peer
path = Path(sys.argv[1]); what = sys.argv[2:]
clean = Path("/work/cache/synthetic/dark-rows-seed0-full")
if "auto" in what:
    r = run_canopy_in_process("dark-rows", path, clean, "auto", 150)
    print("auto", r["tracked_pct"], r["ate_rmse_m"], r["decisions"], flush=True)
if "none" in what:
    r = run_canopy_in_process("dark-rows", path, clean, "none", 150)
    print("none", r["tracked_pct"], r["ate_rmse_m"], r["decisions"], flush=True)
if "orb" in what:
    orb, msg = peer()
    r = run_peer(orb, "euroc", path, None, 150)
    print("orbslam3-raw", r, flush=True)
