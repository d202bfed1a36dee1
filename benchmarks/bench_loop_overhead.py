"""Does the loop closer delay tracking? Tracking service time with loop closing on vs off
(issue 10: "tracking p95 unchanged with it on").

Runs the real multi-process system (``canopy.app.run_slam``, the path of ``launch.py``) on the
same frames with ``--loop`` and ``--no-loop``, interleaved (on, off, on, off, ...) so that a
change of machine load falls on both modes alike. Per run: tracking service time p50 / p95 / max
(ms, from stats.json), the loop closer's own p50 / p95, loops closed, ATE, and the 1-minute load
average before and after. Default sequences: the generated day-loop (first 400 frames; no loop
closes there, so this is the cost of running the loop closer beside tracking: its process,
tracking's place memory, the extra messages) and the KITTI 06 snippet. Lockstep clock (the
default): the same frames and keyframes in both modes.

    python benchmarks/bench_loop_overhead.py [--pairs 2] [--spread-pairs 0] [--day-frames 400] [--only day-loop|kitti]
                                             [--heartbeat-timeout 60] [--out docs/results/bench_loop_overhead.json]

``--spread-pairs N`` also runs N on/on pairs (loop closing on in both runs, back to back): the
on-minus-on differences of tracking p95 are the run-to-run spread at that load, printed beside the
on-minus-off differences, so a difference between the modes can be read against it.

Timing on a shared machine is noisy: compare the modes within a pair and read the load average.
The loop closer's service time (stats.json) is its actor's hand-over of each keyframe; its worker
thread's real time per keyframe is reported as ``loop_worker_step_p50_ms`` / ``_p95_ms``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import statistics
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from canopy.app import run_slam  # noqa: E402
from canopy.report import write_json  # noqa: E402


def sequences(day_frames: int) -> list[dict]:
    return [{"name": f"day-loop ({day_frames} frames)", "key": "day-loop", "dataset": "synthetic",
             "preset": "day-loop", "max_frames": day_frames},
            {"name": "KITTI 06 snippet", "key": "kitti", "dataset": "kitti", "preset": None, "max_frames": None}]


def one_run(seq: dict, loop: bool, out: Path, config: str | None = None, kind: str = "pair") -> dict:
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    res = run_slam(seq["dataset"], preset=seq["preset"], max_frames=seq["max_frames"], out=str(out),
                   progress=False, loop=loop, config=config)
    wall = time.perf_counter() - t0
    stats = json.loads((out / "stats.json").read_text())
    metrics = json.loads((out / "metrics.json").read_text())
    trk = stats["tracking"]["service_ms"]
    lc = stats.get("loop_closing", {}).get("service_ms", {})
    lc_extra = stats.get("loop_closing", {}).get("extra", {})
    if trk.get("p50") is None:  # no frame tracked (the run failed early)
        trk = {"p50": float("nan"), "p95": float("nan"), "max": float("nan")}
    return {"loop": loop, "kind": kind, "loop_worker_step_p50_ms": lc_extra.get("step_ms_p50"),
            "loop_worker_step_p95_ms": lc_extra.get("step_ms_p95"), "ok": res.outcome.ok, "outcome": res.outcome.reason, "tracking_p50_ms": trk["p50"], "tracking_p95_ms": trk["p95"],
            "tracking_max_ms": trk["max"], "loop_closer_p50_ms": lc.get("p50"), "loop_closer_p95_ms": lc.get("p95"),
            "loops": int((metrics.get("loops") or {}).get("closed", 0)),
            "ate_m": (metrics.get("ate") or {}).get("rmse"), "frames": stats["tracking"]["messages"],
            "keyframes": stats["tracking"].get("extra", {}).get("keyframes"),
            "load_before": load_before, "load_after": os.getloadavg()[0], "wall_s": wall}


def config_with_heartbeat(seq: dict, timeout_s: float | None, folder: Path) -> str | None:
    """The dataset's config with another heartbeat timeout (None: the dataset's own config)."""
    if timeout_s is None:
        return None
    src = ROOT / "configs" / f"{seq['dataset']}.yaml"
    text = re.sub(r"(heartbeat_timeout_s:\s*)[0-9.]+", lambda m: f"{m.group(1)}{timeout_s}", src.read_text())
    out = folder / f"{seq['dataset']}_heartbeat{timeout_s:g}.yaml"
    out.write_text(text)
    return str(out)


def summarise(runs: list[dict]) -> dict:
    out = {}
    pairs = [r for r in runs if r.get("kind", "pair") == "pair"]
    for mode in (True, False):
        sel = [r for r in pairs if r["loop"] is mode and r["ok"]]
        if sel:
            out["on" if mode else "off"] = {
                "runs": len(sel),
                "tracking_p50_ms_median": statistics.median(r["tracking_p50_ms"] for r in sel),
                "tracking_p95_ms_median": statistics.median(r["tracking_p95_ms"] for r in sel),
                "tracking_p95_ms_all": [round(r["tracking_p95_ms"], 1) for r in sel],
                "load_mean": statistics.mean((r["load_before"] + r["load_after"]) / 2 for r in sel)}
    if "on" in out and "off" in out:
        out["p95_on_minus_off_ms"] = out["on"]["tracking_p95_ms_median"] - out["off"]["tracking_p95_ms_median"]
        # within each on/off pair (same load, minutes apart): the fairest comparison on a busy machine
        on = [r for r in pairs if r["loop"]]
        off = [r for r in pairs if not r["loop"]]
        out["p95_pair_differences_ms"] = [round(a["tracking_p95_ms"] - b["tracking_p95_ms"], 1) for a, b in zip(on, off)]
    spread = [r for r in runs if r.get("kind") == "spread"]
    if spread:
        # on/on pairs: the difference two runs of the same mode show at this load
        diffs = [round(a["tracking_p95_ms"] - b["tracking_p95_ms"], 1) for a, b in zip(spread[0::2], spread[1::2])
                 if a["ok"] and b["ok"]]
        out["p95_on_on_differences_ms"] = diffs
        if diffs:
            out["p95_run_to_run_spread_ms"] = max(abs(d) for d in diffs)
        out["spread_load_mean"] = statistics.mean((r["load_before"] + r["load_after"]) / 2 for r in spread)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=2, help="on/off pairs per sequence (interleaved)")
    ap.add_argument("--spread-pairs", type=int, default=0, metavar="N",
                    help="also run N on/on pairs: the run-to-run spread of tracking p95 beside the on-off difference")
    ap.add_argument("--day-frames", type=int, default=400)
    ap.add_argument("--only", choices=("day-loop", "kitti"), default=None)
    ap.add_argument("--heartbeat-timeout", type=float, default=None, metavar="S",
                    help="run with a copy of the dataset's config whose runtime.heartbeat_timeout_s is S "
                         "(a machine at load 20+ can stall an actor past the 5 s default)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_loop_overhead.json"))
    args = ap.parse_args(argv)

    report = {"benchmark": "bench_loop_overhead", "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(),
                          "python": platform.python_version()},
              "command": "python benchmarks/bench_loop_overhead.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "sequences": []}
    print(f"{'sequence':24s} {'loop':4s} {'trk p50':>8s} {'trk p95':>8s} {'trk max':>8s} {'LC p95':>8s} {'LCw p95':>8s} "
          f"{'loops':>5s} {'ATE m':>7s} {'load':>10s}   (on*: on/on spread pair; LCw: loop worker step)")
    with tempfile.TemporaryDirectory(prefix="bench_loop_overhead_") as tmp:
        for seq in sequences(args.day_frames):
            if args.only and seq["key"] != args.only:
                continue
            runs = []
            plan = [("pair", pair, loop) for pair in range(args.pairs) for loop in (True, False)]  # A B A B
            plan += [("spread", pair, True) for pair in range(args.spread_pairs) for _ in range(2)]  # A A
            for i, (kind, pair, loop) in enumerate(plan):
                r = one_run(seq, loop, Path(tmp) / f"{seq['key']}-{kind}-{i}-{int(loop)}",
                            config_with_heartbeat(seq, args.heartbeat_timeout, Path(tmp)), kind=kind)
                runs.append(r)
                lc = f"{r['loop_closer_p95_ms']:8.1f}" if r["loop_closer_p95_ms"] is not None else f"{'-':>8s}"
                lw = f"{r['loop_worker_step_p95_ms']:8.1f}" if r["loop_worker_step_p95_ms"] is not None else f"{'-':>8s}"
                ate = f"{r['ate_m']:7.4f}" if r["ate_m"] is not None else f"{'-':>7s}"
                print(f"{seq['name']:24s} {('on' if loop else 'off') + ('*' if kind == 'spread' else ''):4s} "
                      f"{r['tracking_p50_ms']:8.1f} {r['tracking_p95_ms']:8.1f} {r['tracking_max_ms']:8.1f} {lc} {lw} "
                      f"{r['loops']:5d} {ate} {r['load_before']:4.1f}->{r['load_after']:4.1f}"
                      + ("" if r["ok"] else f"  FAILED: {r['outcome']}"), flush=True)
            summary = summarise(runs)
            report["sequences"].append({"name": seq["name"], "runs": runs, "summary": summary})
            if "p95_on_minus_off_ms" in summary:
                print(f"  -> tracking p95 median on {summary['on']['tracking_p95_ms_median']:.1f} ms, off "
                      f"{summary['off']['tracking_p95_ms_median']:.1f} ms; per pair on-off "
                      f"{summary['p95_pair_differences_ms']} ms", flush=True)
            if "p95_on_on_differences_ms" in summary:
                print(f"  -> run-to-run spread (on/on pairs) {summary['p95_on_on_differences_ms']} ms", flush=True)
    write_json(args.out, report)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
