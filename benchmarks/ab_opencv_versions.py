#!/usr/bin/env python
"""CPU per frame of the same code under two OpenCV builds (e.g. 5.0 vs 5.1), interleaved A/B.

Each repetition runs, in the order A, B (then B, A on the next repetition), in each interpreter:
- the extractors: ``bench_extractors.bench`` on the KITTI 06 / EuRoC snippets (process CPU ms per
  image, OpenCV's worker threads included);
- a whole lockstep run: ``launch.py --dataset kitti --quiet``, its CPU (launcher + actors, from
  ``getrusage(RUSAGE_CHILDREN)``) and the actors' thread CPU (``stats.json``) per frame, and whether
  its ``trajectory.tum`` is byte-equal to the other interpreter's.
The two interpreters share the code (this checkout, on PYTHONPATH); only the cv2 they import differs.
Prints one table (median and range over the repetitions) and writes JSON. CPU time, not wall time,
because the machine is shared; quote the load average beside the numbers.

    python benchmarks/ab_opencv_versions.py --a python --b /work/venv51/bin/python --reps 4 \\
        --out docs/results/s16_cv51/ab_opencv_versions.json
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]

# run inside the interpreter under test: its cv2 version and the extractor timings as JSON
EXTRACTOR_PROBE = """
import json, sys, cv2
sys.path.insert(0, {root!r}); sys.path.insert(0, {root!r} + "/benchmarks")
from bench_extractors import bench
print(json.dumps({{"cv2": cv2.__version__, "rows": {{d: bench(d, {frames}, 1) for d in {datasets!r}}}}}))
"""


def _env() -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.setdefault("CANOPY_CACHE_DIR", str(ROOT / "cache"))
    return env


def extractor_cpu(python: str, frames: int, datasets: list[str]) -> dict:
    code = EXTRACTOR_PROBE.format(root=str(ROOT), frames=frames, datasets=datasets)
    out = subprocess.run([python, "-c", code], check=True, capture_output=True, text=True, env=_env(), cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def kitti_run_cpu(python: str, out_dir: Path) -> dict:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run([python, "launch.py", "--dataset", "kitti", "--quiet", "--out", str(out_dir)],
                          capture_output=True, text=True, env=_env(), cwd=ROOT)
    if done.returncode != 0:
        raise RuntimeError(f"{python} launch.py --dataset kitti exited {done.returncode}:\n{done.stderr[-3000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    stats = json.loads((out_dir / "stats.json").read_text())
    frames = stats["tracking"]["messages"]
    actors = {name: sum(t["cpu_s"] for t in s["extra"]["threads"].values()) * 1e3 / frames
              for name, s in stats.items() if "threads" in s.get("extra", {})}
    return {"frames": frames, "total_cpu_ms_per_frame": cpu_s * 1e3 / frames,
            "actors_cpu_ms_per_frame": actors, "trajectory": (out_dir / "trajectory.tum").read_bytes()}


def _summary(values: list[float]) -> dict:
    return {"median": float(np.median(values)), "min": float(np.min(values)), "max": float(np.max(values)),
            "values": [float(v) for v in values]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--a", required=True, help="interpreter A (e.g. python, with opencv 5.0)")
    ap.add_argument("--b", required=True, help="interpreter B (e.g. /work/venv51/bin/python)")
    ap.add_argument("--reps", type=int, default=4)
    ap.add_argument("--frames", type=int, default=30, help="extractor images per dataset")
    ap.add_argument("--datasets", nargs="*", default=["kitti", "euroc"])
    ap.add_argument("--extractors-only", action="store_true", help="skip the KITTI runs (more reps per minute)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "ab_opencv_versions.json"))
    args = ap.parse_args(argv)
    pythons = {"A": args.a, "B": args.b}
    load = [os.getloadavg()]
    ext = {k: [] for k in pythons}
    run = {k: [] for k in pythons}
    versions = {}
    equal = []
    with tempfile.TemporaryDirectory() as tmp:
        for rep in range(args.reps):
            order = ["A", "B"] if rep % 2 == 0 else ["B", "A"]
            trajectories = {}
            for k in order:
                e = extractor_cpu(pythons[k], args.frames, args.datasets)
                versions[k] = e["cv2"]
                ext[k].append(e["rows"])
                if not args.extractors_only:
                    r = kitti_run_cpu(pythons[k], Path(tmp) / f"{k}{rep}")
                    trajectories[k] = r.pop("trajectory")
                    run[k].append(r)
            if not args.extractors_only:
                equal.append(trajectories["A"] == trajectories["B"])
            load.append(os.getloadavg())
            print(f"rep {rep + 1}/{args.reps} done, load {load[-1][0]:.1f}", flush=True)
    result = {"benchmark": "ab_opencv_versions", "cores": os.cpu_count(), "load_average": load,
              "interpreters": {k: {"python": pythons[k], "cv2": versions[k]} for k in pythons},
              "kitti_trajectory_byte_equal": equal, "extractor_cpu_ms_per_image": {}, "kitti_run": {}}
    print(f"A = cv2 {versions['A']} ({args.a}), B = cv2 {versions['B']} ({args.b}); {args.reps} reps, "
          f"CPU ms, median [min-max]")
    for d in args.datasets:
        for name in ext["A"][0][d]:
            row = {k: _summary([r[d][name]["cpu_ms_mean"] for r in ext[k]]) for k in pythons}
            result["extractor_cpu_ms_per_image"][f"{d}/{name}"] = row
            a, b = row["A"], row["B"]
            ratios = [vb / va for va, vb in zip(a["values"], b["values"])]
            row["B_over_A_per_rep"] = ratios
            print(f"extractor {d:<6} {name:<7} A {a['median']:6.2f} [{a['min']:.2f}-{a['max']:.2f}]  "
                  f"B {b['median']:6.2f} [{b['min']:.2f}-{b['max']:.2f}]  B/A {b['median'] / a['median']:.3f}  "
                  f"per rep {np.median(ratios):.3f} [{min(ratios):.2f}-{max(ratios):.2f}], B slower in "
                  f"{sum(x > 1 for x in ratios)}/{len(ratios)}")
    keys = [] if args.extractors_only else \
        ["total_cpu_ms_per_frame"] + [f"actor:{n}" for n in run["A"][0]["actors_cpu_ms_per_frame"]]
    for key in keys:
        pick = (lambda r: r["total_cpu_ms_per_frame"]) if key == "total_cpu_ms_per_frame" else \
            (lambda r, n=key.split(":")[1]: r["actors_cpu_ms_per_frame"][n])
        row = {k: _summary([pick(r) for r in run[k]]) for k in pythons}
        result["kitti_run"][key] = row
        a, b = row["A"], row["B"]
        print(f"kitti run {key:<24} A {a['median']:7.1f} [{a['min']:.1f}-{a['max']:.1f}]  "
              f"B {b['median']:7.1f} [{b['min']:.1f}-{b['max']:.1f}]  B/A {b['median'] / a['median']:.3f}")
    print(f"KITTI trajectory byte-equal A vs B: {equal}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
