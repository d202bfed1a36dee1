"""s17-motionprior sweep: KITTI g0.15-b0.06-high and g1-b0.06-high, noise seeds 0-4, clean KITTI
(from the seed-0 call), per variant of tracking.motion_prior_sigma_deg / _m, through
benchmarks/bench_degrade_grid.py --in-process (deterministic: ATE does not depend on load).

usage: python docs/results/s17_motionprior/sweep.py OUT.json VARIANT [VARIANT ...]
VARIANT = "deg,m[,gate_deg]" (e.g. "0,0" = main, "0.1,0.02", "0.05,0.01,0.04": tracking.motion_prior_min_rot_std_deg,
"0.05,0.01,0,5": tracking.motion_prior_pose_var_factor).
"""
import json
import subprocess
import sys
import tempfile
from pathlib import Path

CACHE = {0: "/work/cache/degraded", 1: "/work/cache/degraded", 2: "/work/cache/degraded",
         3: "/work/cache/degraded_kittihaze", 4: "/work/cache/degraded_kittihaze"}


def run(seed: int, deg: float, m: float, gate: float, var_factor: float, clean: bool, dataset="kitti", gains=("0.15", "1"), betas=("0.06",),
        noise="high") -> list[dict]:
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "benchmarks/bench_degrade_grid.py", "--in-process", "--cells-cache", CACHE[seed],
               "--datasets", dataset, "--gains", *gains, "--betas", *betas, "--noise", noise, "--methods", "auto",
               "--peers", "--seed", str(seed), "--set", f"tracking.motion_prior_sigma_deg={deg}",
               "--set", f"tracking.motion_prior_sigma_m={m}", "--out-dir", out]
        if gate > 0:
            cmd += ["--set", f"tracking.motion_prior_min_rot_std_deg={gate}"]
        if var_factor > 0:
            cmd += ["--set", f"tracking.motion_prior_pose_var_factor={var_factor}"]
        if not clean:
            cmd.append("--skip-clean")
        subprocess.run(cmd, check=True, capture_output=True)
        return json.loads((Path(out) / "bench_degrade_grid.json").read_text())["rows"]


def main():
    out = Path(sys.argv[1])
    res = json.loads(out.read_text()) if out.exists() else {}
    for v in sys.argv[2:]:
        deg, m, gate, var_factor = ([float(x) for x in v.split(",")] + [0.0, 0.0])[:4]
        rows = res.setdefault(v, {})
        for seed in range(5):
            for r in run(seed, deg, m, gate, var_factor, clean=(seed == 0)):
                key = f"{r['cell']}" + ("" if r["cell"] == "clean" else f"-seed{seed}")
                rows[key] = {"tracked_pct": r["tracked_pct"], "ate_mm": None if r["ate_rmse_m"] is None
                             else 1000 * r["ate_rmse_m"]}
                print(v, key, rows[key], flush=True)
            out.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
