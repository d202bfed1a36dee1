#!/usr/bin/env python
"""Canopy beside ORB-SLAM3 stereo on the same frames, in one run (issue 8).

Per sequence, interleaved: Canopy through its actors (lockstep, the dataset's default
config, via ``canopy.app.run_slam``), Canopy with ``--enhance auto``, then N repetitions
of ORB-SLAM3 on the raw frames and of ORB-SLAM3 fed Canopy's enhanced frames (``auto``:
the AFE-ORB-SLAM configuration). ORB-SLAM3 is not deterministic, hence the repetitions.

    CANOPY_CACHE_DIR=/work/cache python benchmarks/bench_peers.py            # everything, 3 reps
    CANOPY_CACHE_DIR=/work/cache python benchmarks/bench_peers.py --quick    # short: ~10 min on 2 cores
    CANOPY_CACHE_DIR=/work/cache python benchmarks/bench_peers.py --sequences kitti euroc \
        --systems canopy orbslam3 --reps 3 --canopy-reps 3 --no-pace --out docs/results/bench_peers_speed.json  # speed

Sequences: the bundled KITTI 06 and EuRoC V1_01 snippets, the generated presets
day-loop, dusk-loop, haze-row, dark-rows (seed 0), and darkened / hazy copies of the
KITTI snippet made with ``tools/degrade_sequence.py`` (cached). Prints one table (ATE
RMSE after SE(3) alignment with canopy.metrics, tracked %, path-length error, tracking ms
p50/p95 per frame, frames/s, CPU) and writes ``docs/results/bench_peers.json``.

Columns: *track ms* is Canopy's tracking actor service time per frame and ORB-SLAM3's
``track_stereo()`` call; *fps* is Canopy's lockstep throughput (frames / wall time of the
run) and ORB-SLAM3's tracking rate (frames / summed ``track_stereo()`` time; it is fed
at the sequence rate, its mapping runs in its own threads); *stream* is Canopy's lockstep
throughput between its first and last tracked frame (without process start-up and shutdown,
which *fps* includes); *thr cpu* / *rq wait* are the tracking thread's CPU time and run-queue
wait (runnable, no free core; ``/proc/self/task/<tid>/schedstat``) per frame: Canopy's tracking
actor main thread (its worker thread is in the JSON), ORB-SLAM3's calling thread; *CPU %* is the sum of
Canopy's actors' mean CPU, and ORB-SLAM3's process CPU time over its feeding time (100 =
one core). Without ``pyorbslam3`` the ORB-SLAM3 rows are skipped with the install hint.
"""
from __future__ import annotations

import argparse
import csv
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.peers import orbslam3  # noqa: E402
from canopy.app import prepare_synthetic, run_slam  # noqa: E402
from canopy.config import load_run_config  # noqa: E402
from canopy.enhance import make_enhancer  # noqa: E402
from canopy.metrics import associate, evaluate_trajectory  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402
from canopy.trajectory_io import read_tum  # noqa: E402
from shared.types import Trajectory  # noqa: E402

PRESETS = ("day-loop", "dusk-loop", "haze-row", "dark-rows")
# Degraded copies of the KITTI snippet: (name, tools/degrade_sequence.py arguments).
DEGRADED = {"kitti-dark": ["--mode", "dark", "--gain", "0.15"],
            "kitti-haze": ["--mode", "haze", "--beta", "0.05"]}
QUICK_FRAMES = {"day-loop": 300, "dusk-loop": 300, "haze-row": 200, "dark-rows": 200}
SYSTEMS = ("canopy", "canopy+auto", "orbslam3", "orbslam3+auto")
OUT = ROOT / "docs" / "results" / "bench_peers.json"
# A path-length error in % means nothing on a (nearly) static sequence such as the EuRoC snippet.
MIN_PATH_FOR_LENGTH_ERROR_M = 1.0


# ----------------------------------------------------------------------------- sequences

def degraded_copy(name: str, progress: bool) -> Path:
    out = orbslam3.cache_dir() / "peers" / name
    if not (out / "DEGRADED.yaml").is_file():
        if progress:
            print(f"  making {name} with tools/degrade_sequence.py ...", flush=True)
        done = subprocess.run([sys.executable, str(ROOT / "tools" / "degrade_sequence.py"), "--dataset", "kitti",
                               "--out", str(out), "--force", *DEGRADED[name]], capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        if done.returncode != 0:
            raise SystemExit(f"tools/degrade_sequence.py failed for {name}: {done.stderr.strip()[-500:]}")
    return out


def sequences(names: list[str], quick: bool, progress: bool) -> list[dict]:
    """Each: name, dataset for run_slam, dataset kind + path for the sources, max_frames."""
    out = []
    for name in names:
        if name in ("kitti", "euroc"):
            out.append({"name": name, "run_dataset": name, "kind": name, "path": None, "preset": None,
                        "max_frames": None})
        elif name in PRESETS:
            path = prepare_synthetic(name, None, 0, progress)
            out.append({"name": name, "run_dataset": "synthetic", "kind": "euroc", "path": path, "preset": name,
                        "max_frames": QUICK_FRAMES[name] if quick else None})
        elif name in DEGRADED:
            out.append({"name": name, "run_dataset": "kitti", "kind": "kitti",
                        "path": str(degraded_copy(name, progress)), "preset": None, "max_frames": None})
        else:
            raise SystemExit(f"unknown sequence {name!r}; choose from kitti, euroc, {', '.join(PRESETS)}, "
                             f"{', '.join(DEGRADED)}")
    return out


# ----------------------------------------------------------------------------- metrics

def trajectory_metrics(est: Trajectory, gt: Trajectory | None, total: int) -> dict:
    """ATE (SE(3) aligned), tracked %, path-length error over the matched frames."""
    out = {"ate_rmse_m": None, "tracked_percent": 100.0 * len(est) / total if total else None,
           "path_error_percent": None, "n_matched": 0}
    if gt is None or len(est) < 3:
        return out
    ev = evaluate_trajectory(est, gt)
    out["n_matched"] = ev["n_matched"]
    # end-to-end motion: the EuRoC snippet is static (the bound of issue 8: < 1 cm, < 0.5 deg)
    out["est_translation_m"] = ev["est_motion"]["translation_m"]
    out["est_rotation_deg"] = ev["est_motion"]["rotation_deg"]
    if ev["ate"] is not None:
        out["ate_rmse_m"] = ev["ate"]["rmse"]
        ia, ib = associate(est.stamps, gt.stamps, ev["max_diff_s"])
        gt_len = Trajectory(gt.stamps[ib], gt.poses[ib]).path_length()
        if gt_len >= MIN_PATH_FOR_LENGTH_ERROR_M:
            out["path_error_percent"] = 100.0 * (Trajectory(est.stamps[ia], est.poses[ia]).path_length()
                                                 - gt_len) / gt_len
    return out


def config_with_heartbeat(dataset: str, timeout_s: float | None, folder: Path) -> str | None:
    """The dataset's default config with only ``runtime.heartbeat_timeout_s`` changed (None: the
    default file). On a machine loaded far beyond its cores an actor can miss its 5 s heartbeat
    and the supervisor stops the run; that is the machine, not the algorithm."""
    if timeout_s is None:
        return None
    import yaml

    from canopy.config import default_config_path
    raw = yaml.safe_load(default_config_path(dataset).read_text()) or {}
    raw.setdefault("runtime", {})["heartbeat_timeout_s"] = float(timeout_s)
    path = folder / f"{dataset}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


def run_canopy(seq: dict, enhance: str | None, heartbeat_s: float | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        config = config_with_heartbeat(seq["run_dataset"], heartbeat_s, Path(tmp))
        res = run_slam(seq["run_dataset"], path=seq["path"], preset=seq["preset"], clock="lockstep",
                       enhance=enhance, max_frames=seq["max_frames"], out=str(Path(tmp) / "run"),
                       progress=False, config=config)
        traj_file = res.out_dir / "trajectory.tum"
        est = read_tum(traj_file) if traj_file.is_file() and traj_file.stat().st_size else \
            Trajectory(np.zeros(0), np.zeros((0, 4, 4)))
        with open(res.out_dir / "frames.csv", newline="") as fh:
            lost_stamps = np.array([float(r["timestamp"]) for r in csv.DictReader(fh) if r["status"] == "lost"])
    m, s = res.summary["metrics"], res.summary["stats"]
    src = open_source(seq["kind"], seq["path"], max_frames=seq["max_frames"])
    total = m["tracking"]["frames_total"]
    # Canopy writes a pose for lost frames too; like ORB-SLAM3's, keep only tracked ones
    keep = ~np.isin(np.round(est.stamps, 6), np.round(lost_stamps, 6)) if len(lost_stamps) else \
        np.ones(len(est), bool)
    row = trajectory_metrics(Trajectory(est.stamps[keep], est.poses[keep]), src.ground_truth, total)
    row["ate_all_frames_m"] = (m.get("ate") or {}).get("rmse")  # Canopy's own metrics.json figure
    # over all frames of the sequence: a run that stopped early has not tracked the rest
    tracked = 100.0 * (m["tracking"]["frames_processed"] - m["tracking"]["frames_lost"]) / total if total else None
    row.update({"tracked_percent": tracked,
                "track_ms_p50": s["tracking"]["service_ms"]["p50"], "track_ms_p95": s["tracking"]["service_ms"]["p95"],
                "fps": m["run"]["frames_per_s"], "fps_streaming": streaming_fps(s, total),
                "cpu_percent": float(sum((a.get("cpu_percent") or {}).get("mean") or 0.0 for a in s.values())),
                "frames": total, "keyframes": m["tracking"]["keyframes"], "lost": m["tracking"]["frames_lost"],
                "outcome": res.outcome.reason, "wall_s": res.outcome.wall_s, "resets": None, "loops": 0})
    row.update(thread_columns(((s.get("tracking") or {}).get("extra") or {}).get("threads")))
    return row


def thread_columns(threads: dict | None) -> dict:
    """The tracking thread's CPU and run-queue wait per frame (``actors.schedstat``: Canopy's
    tracking actor main thread, ORB-SLAM3's calling thread): whether tracking time is computing or
    waiting for a core."""
    t = (threads or {}).get("tracking") or {}
    return {"track_cpu_ms": t.get("cpu_ms_per_frame"), "track_wait_ms": t.get("runqueue_wait_ms_per_frame"),
            "threads": threads}


def streaming_fps(stats: dict, frames: int) -> float | None:
    """Frames per second between the first and the last tracked frame (the tracking actor's
    ``first_frame_done_at`` / ``last_frame_done_at``): lockstep throughput without the ~1-3 s of
    process start-up and shutdown that ``frames_per_s`` (frames / run wall time) includes."""
    extra = (stats.get("tracking") or {}).get("extra") or {}
    t0, t1 = extra.get("first_frame_done_at"), extra.get("last_frame_done_at")
    if t0 is None or t1 is None or t1 <= t0 or frames < 2:
        return None
    return (frames - 1) / (t1 - t0)


def stereo_enhancer(method: str, kind: str):
    """preprocess(left, right) with Canopy's enhancement (right gets the left's decision)."""
    params = replace(load_run_config(kind).enhancement, method=method)
    enhance = make_enhancer(params)

    def preprocess(left, right):
        out_left, info = enhance(left)
        out_right, _ = enhance(right, method=info["method"])
        return out_left, out_right

    preprocess.__name__ = f"canopy_enhance_{method}"
    return preprocess


def run_peer(seq: dict, enhance: str | None, vocabulary: Path, pace: bool) -> dict:
    pre = stereo_enhancer(enhance, seq["kind"]) if enhance else None
    r = orbslam3.run_stereo(seq["path"], seq["kind"], preprocess=pre, vocabulary=vocabulary,
                            max_frames=seq["max_frames"], pace=pace)
    src = open_source(seq["kind"], seq["path"], max_frames=seq["max_frames"])
    row = trajectory_metrics(r.trajectory, src.ground_truth, r.total)
    final = trajectory_metrics(r.final_trajectory, src.ground_truth, r.total) if r.final_trajectory else {}
    ms = r.track_ms[np.isfinite(r.track_ms)] if len(r.track_ms) else np.zeros(0)
    row.update({"track_ms_p50": float(np.percentile(ms, 50)) if len(ms) else None,
                "track_ms_p95": float(np.percentile(ms, 95)) if len(ms) else None,
                "fps": float(len(ms) / (ms.sum() / 1e3)) if ms.sum() > 0 else None,
                "cpu_percent": 100.0 * r.cpu_s / r.wall_s if r.wall_s else None,
                "frames": r.total, "resets": r.resets, "frozen": r.frozen, "loops": r.loops, "wall_s": r.wall_s,
                "final_ate_rmse_m": final.get("ate_rmse_m"), "error": r.error,
                "final_trajectory_error": r.meta.get("final_trajectory_error"),
                "outcome": "error" if r.error else "completed"})
    row.update(thread_columns(r.meta.get("threads")))
    if r.error:
        row["log_tail"] = r.log_tail
    return row


# ----------------------------------------------------------------------------- table

def fmt(v, spec=".3f") -> str:
    return "-" if v is None else format(v, spec)


def summarise(rows: list[dict]) -> list[dict]:
    """One line per (sequence, system): ATE min-max over reps, medians of the rest."""
    table = []
    seq_order = ["kitti", "euroc", *PRESETS, *DEGRADED]

    def order(key):
        seq, system = key
        base = system.split("+")[0] + ("+enh" if "+" in system else "")
        return (seq_order.index(seq) if seq in seq_order else len(seq_order), seq,
                ["canopy", "canopy+enh", "orbslam3", "orbslam3+enh"].index(base))

    for key in sorted(dict.fromkeys((r["sequence"], r["system"]) for r in rows), key=order):
        group = [r for r in rows if (r["sequence"], r["system"]) == key]

        def vals(name):
            return [r[name] for r in group if r.get(name) is not None]

        def med(name):
            v = vals(name)
            return float(np.median(v)) if v else None

        ate = vals("ate_rmse_m")
        table.append({"sequence": key[0], "system": key[1], "reps": len(group),
                      "ate_min_m": min(ate) if ate else None, "ate_max_m": max(ate) if ate else None,
                      "final_ate_min_m": min(vals("final_ate_rmse_m")) if vals("final_ate_rmse_m") else None,
                      "final_ate_max_m": max(vals("final_ate_rmse_m")) if vals("final_ate_rmse_m") else None,
                      **{k: med(k) for k in ("tracked_percent", "path_error_percent", "track_ms_p50",
                                             "track_ms_p95", "fps", "fps_streaming", "cpu_percent",
                                             "track_cpu_ms", "track_wait_ms", "frames")},
                      "resets": sum(vals("resets")) if vals("resets") else None,
                      "loops": sum(vals("loops")),
                      "errors": sum(1 for r in group if r.get("error") or r.get("outcome") != "completed"),
                      "outcomes": sorted({str(r.get("outcome")) for r in group})})
    return table


def format_table(table: list[dict], header: dict) -> str:
    lines = [f"# ORB-SLAM3: {header['orbslam3']}; vocabulary: {header['vocabulary']}; "
             f"cores: {header['cores']}; {header['date']}{'; --quick' if header['quick'] else ''}",
             f"{'sequence':11s} {'system':14s} {'reps':>4s} {'ATE m':>13s} {'final ATE':>13s} {'tracked%':>8s} "
             f"{'path err%':>9s} {'ms p50':>7s} {'ms p95':>7s} {'thr cpu':>7s} {'rq wait':>7s} {'fps':>6s} {'stream':>6s} "
             f"{'CPU%':>5s} {'resets':>6s} "
             f"{'loops':>5s}"]
    for t in table:
        ate = (fmt(t["ate_min_m"]) if t["ate_min_m"] == t["ate_max_m"]
               else f"{fmt(t['ate_min_m'])}-{fmt(t['ate_max_m'])}")
        final = ("" if t["final_ate_min_m"] is None else fmt(t["final_ate_min_m"]) if t["reps"] == 1
                 else f"{fmt(t['final_ate_min_m'])}-{fmt(t['final_ate_max_m'])}")
        lines.append(f"{t['sequence']:11s} {t['system']:14s} {t['reps']:4d} {ate:>13s} {final:>13s} "
                     f"{fmt(t['tracked_percent'], '.1f'):>8s} {fmt(t['path_error_percent'], '+.2f'):>9s} "
                     f"{fmt(t['track_ms_p50'], '.1f'):>7s} {fmt(t['track_ms_p95'], '.1f'):>7s} "
                     f"{fmt(t.get('track_cpu_ms'), '.1f'):>7s} {fmt(t.get('track_wait_ms'), '.1f'):>7s} "
                     f"{fmt(t['fps'], '.1f'):>6s} {fmt(t.get('fps_streaming'), '.1f'):>6s} "
                     f"{fmt(t['cpu_percent'], '.0f'):>5s} {'-' if t['resets'] is None else t['resets']:>6} {t['loops']:>5d}"
                     + (f"  ({t['errors']} run(s) did not complete: {', '.join(t['outcomes'])})"
                        if t["errors"] else ""))
    return "\n".join(lines)


def format_markdown(table: list[dict], header: dict) -> str:
    """The table as Markdown (for the README), with the header line above it."""
    lines = [f"ORB-SLAM3: {header['orbslam3']}; vocabulary: {header['vocabulary']}; cores: {header['cores']}; "
             f"measured {header['date']}.", "",
             "| sequence | system | runs | ATE (m) | final ATE (m) | tracked % | path err % | track ms p50 / p95 "
             "| tracking thread CPU / run-queue wait ms per frame | fps (streaming) | CPU % | resets | loops (all runs) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for t in table:
        ate = (fmt(t["ate_min_m"]) if t["ate_min_m"] == t["ate_max_m"]
               else f"{fmt(t['ate_min_m'])}–{fmt(t['ate_max_m'])}")
        final = ("-" if t["final_ate_min_m"] is None else fmt(t["final_ate_min_m"])
                 if t["final_ate_min_m"] == t["final_ate_max_m"]
                 else f"{fmt(t['final_ate_min_m'])}–{fmt(t['final_ate_max_m'])}")
        note = f" ({t['errors']} incomplete)" if t["errors"] else ""
        lines.append(f"| {t['sequence']} | {t['system']} | {t['reps']}{note} | {ate} | {final} | "
                     f"{fmt(t['tracked_percent'], '.1f')} | {fmt(t['path_error_percent'], '+.2f')} | "
                     f"{fmt(t['track_ms_p50'], '.0f')} / {fmt(t['track_ms_p95'], '.0f')} | "
                     f"{fmt(t.get('track_cpu_ms'), '.1f')} / {fmt(t.get('track_wait_ms'), '.1f')} | {fmt(t['fps'], '.1f')}"
                     f"{'' if t.get('fps_streaming') is None else ' (' + fmt(t['fps_streaming'], '.1f') + ')'} | "
                     f"{fmt(t['cpu_percent'], '.0f')} | {'-' if t['resets'] is None else t['resets']} | {t['loops']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="kitti, euroc, haze-row, dark-rows, kitti-dark; generated sequences cut short; 1 rep")
    ap.add_argument("--sequences", nargs="+", default=None)
    ap.add_argument("--systems", nargs="+", default=list(SYSTEMS), choices=SYSTEMS)
    ap.add_argument("--reps", type=int, default=None, help="ORB-SLAM3 repetitions (default 3, --quick 1)")
    ap.add_argument("--canopy-reps", type=int, default=1,
                    help="Canopy repetitions (deterministic in lockstep: more only for timing)")
    ap.add_argument("--enhance", default="auto", help="Canopy enhancement used by the +enh systems")
    ap.add_argument("--vocabulary", default=None, help="ORB-SLAM3 vocabulary (default: trained and cached)")
    ap.add_argument("--no-pace", action="store_true",
                    help="feed ORB-SLAM3 as fast as it tracks. By default it is fed at the sequence rate as "
                         "upstream's examples do, so its local mapping runs in the idle gaps between frames: "
                         "its track_stereo() then meets a quieter machine than Canopy's lockstep tracking, "
                         "which never idles. For the tracking-speed comparison use --no-pace (like for like)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--resume", action="store_true",
                    help="keep the runs already in --out and skip the (sequence, system) pairs they cover")
    ap.add_argument("--heartbeat-timeout", type=float, default=None, metavar="S",
                    help="Canopy's actor heartbeat timeout (default: the config's 5 s); raise it on an "
                         "overloaded machine, where a missed heartbeat stops the run")
    ap.add_argument("--markdown", type=Path, default=None, metavar="JSON",
                    help="print the Markdown table of a saved run and exit (nothing is run)")
    a = ap.parse_args(argv)
    if a.markdown is not None:
        import json
        saved = json.loads(a.markdown.read_text())
        print(format_markdown(summarise(saved["runs"]), saved["header"]))
        return 0
    names = a.sequences or (["kitti", "euroc", "haze-row", "dark-rows", "kitti-dark"] if a.quick else
                            ["kitti", "euroc", *PRESETS, *DEGRADED])
    reps = a.reps if a.reps is not None else (1 if a.quick else 3)
    ok, how = orbslam3.available()
    systems = [s.replace("+auto", f"+{a.enhance}") for s in a.systems]
    if not ok:
        print(f"ORB-SLAM3 rows skipped: {how}")
        systems = [s for s in systems if not s.startswith("orbslam3")]
    vocabulary = orbslam3.peer_vocabulary(a.vocabulary) if ok else None
    vocab_note = "-"
    if vocabulary is not None:
        from canopy.place import Vocabulary
        v = Vocabulary.load(vocabulary)
        vocab_note = f"{vocabulary.name} (ours, k={v.k} L={v.levels}, {v.words} words)"
    header = {"orbslam3": orbslam3.version() if ok else f"not run ({how})", "vocabulary": vocab_note,
              "vocabulary_path": str(vocabulary) if vocabulary else None, "cores": os.cpu_count(),
              "date": time.strftime("%Y-%m-%d %H:%M"), "quick": a.quick, "reps": reps,
              "enhance": a.enhance, "pace": not a.no_pace, "heartbeat_timeout_s": a.heartbeat_timeout, "python": platform.python_version(),
              "machine_note": "shared 2-core machine, other work running: timings are noisy"}
    rows = []
    if a.resume and a.out.is_file():
        import json
        rows = json.loads(a.out.read_text()).get("runs", [])
        print(f"resuming: {len(rows)} runs kept from {a.out}")
    done = {(r["sequence"], r["system"]) for r in rows}
    for seq in sequences(names, a.quick, progress=True):
        # interleaved: Canopy and ORB-SLAM3 alternate, so the machine's load falls on both alike
        n_rounds = max(reps, a.canopy_reps)
        plan = [(s, rep) for rep in range(n_rounds) for s in systems
                if (s.startswith("canopy") and rep < a.canopy_reps) or (s.startswith("orbslam3") and rep < reps)]
        plan = [(s, rep) for s, rep in plan if (seq["name"], s) not in done]
        for system, rep in plan:
            enhance = a.enhance if "+" in system else None
            t0 = time.monotonic()
            print(f"  {seq['name']:11s} {system:14s} rep {rep if rep is not None else '-'} ...", end="", flush=True)
            row = (run_canopy(seq, enhance, a.heartbeat_timeout) if system.startswith("canopy")
                   else run_peer(seq, enhance, vocabulary, not a.no_pace))
            row.update({"sequence": seq["name"], "system": system, "rep": rep,
                        "max_frames": seq["max_frames"], "bench_s": time.monotonic() - t0})
            rows.append(row)
            print(f" ATE {fmt(row['ate_rmse_m'])} m, tracked {fmt(row['tracked_percent'], '.0f')} %, "
                  f"{row['bench_s']:.0f} s", flush=True)
        # after every sequence, so a long run that is stopped keeps what it measured
        write_json(a.out, {"header": {**header, "partial": True}, "table": summarise(rows), "runs": rows,
                           "command": " ".join(sys.argv)})
    table = summarise(rows)
    print(format_table(table, header))
    write_json(a.out, {"header": header, "table": table, "runs": rows, "command": " ".join(sys.argv)})
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
