#!/usr/bin/env python
"""Load test of every actor (issue 12): which actor saturates first, at which frame rate.

Runs the real multi-process system (``canopy.app.run_slam``, the path of ``launch.py``) on the
bundled EuRoC-size (752x480, V1_01 micro slice) and KITTI-size (1226x370, KITTI 06 snippet)
sequences, with the source releasing frames at 10, 20, 30, 40, 60 Hz (realtime clock,
``runtime.realtime_speed`` = rate / dataset rate) and as fast as possible (lockstep: each frame
fully processed before the next), with and without enhancement (``agri``, the dehazing of the
stereo paper, applied to every frame) and line segments, with 0 and N inspection subscribers
(``--inspect`` on loopback, N SUB sockets in a separate client process decoding every event).

Per run and per actor: service time and queue wait p50/p95/p99, drops, mean CPU %, peak RSS;
per run: end-to-end latency (source starts reading the frame -> tracking publishes its pose,
``FrameHandle.read_at`` / ``FramePose.frame_read_at``) p50/p95/p99, frames dropped (any actor),
achieved pose rate. The **saturation rate** of a configuration is the highest rate with < 1 %
frames dropped and bounded latency (the last third of the run's end-to-end p95 at most
``LATENCY_GROWTH`` x the first third's plus one frame period: a queue that keeps growing is not
bounded). Lockstep gives the throughput ceiling (poses/s).

``--compare-pairs N`` then measures what N inspection subscribers cost tracking: 0 and N
subscribers interleaved A B A B (N pairs, lockstep, EuRoC-size), tracking service p50 per run,
the median of the per-pair changes (issue 12: <= 5 %). On a shared machine every number here is
noisy; re-run on a quiet one.

    python benchmarks/bench_load.py --quick             # 8 runs + 2 comparison pairs (~4 min)
    python benchmarks/bench_load.py                     # the full grid: 96 runs + 3 pairs
    python benchmarks/bench_load.py --sizes euroc --rates 20 lockstep --subscribers 0 20
"""
from __future__ import annotations

import argparse
import itertools
import multiprocessing as mp
import os
import platform
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import psutil  # noqa: E402
import yaml  # noqa: E402

from canopy.app import run_slam  # noqa: E402
from canopy.config import default_config_path  # noqa: E402
from canopy.report import write_json  # noqa: E402
from canopy.sources import open_source  # noqa: E402

SIZES = {"euroc": "EuRoC 752x480", "kitti": "KITTI 1226x370"}
RATES = ("10", "20", "30", "40", "60", "lockstep")
ACTORS = ("source", "enhancement", "tracking", "local_mapping", "loop_closing")
MAX_DROP_FRACTION = 0.01        # saturation: < 1 % of the frames dropped ...
LATENCY_GROWTH = 1.5            # ... and end-to-end p95 not growing over the run
ENHANCE_ON = "agri"             # enhances every frame (auto may pass clean frames through)
SUBSCRIBER_TIMEOUT_S = 600.0


# -- inspection subscribers (a separate process, as remote clients would be) -----------------------

def _subscribers_main(endpoint: str, n: int, ready, done, counts) -> None:
    import zmq

    from protocol.codec import decode
    zctx = zmq.Context()
    socks = []
    for _ in range(n):
        s = zctx.socket(zmq.SUB)
        s.setsockopt(zmq.SUBSCRIBE, b"")
        s.setsockopt(zmq.LINGER, 0)
        s.connect(endpoint)
        socks.append(s)
    poller = zmq.Poller()
    for s in socks:
        poller.register(s, zmq.POLLIN)
    ended: set[int] = set()
    received = 0
    ready.set()
    deadline = time.monotonic() + SUBSCRIBER_TIMEOUT_S
    while len(ended) < n and not done.is_set() and time.monotonic() < deadline:
        for s, _ in poller.poll(100):
            kind, payload = s.recv_multipart()
            decode(payload)  # a real client decodes every event
            received += 1
            if kind == b"run_end":
                ended.add(id(s))
    counts.value = received
    for s in socks:
        s.close()
    zctx.term()


def _free_port_pair() -> int:
    """A port p with p and p + 1 both free (--inspect uses p + 1 for requests)."""
    for _ in range(50):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port >= 65534:
            continue
        with socket.socket() as s2:
            try:
                s2.bind(("127.0.0.1", port + 1))
                return port
            except OSError:
                continue
    raise RuntimeError("no free pair of loopback ports")


# -- one run ---------------------------------------------------------------------------------------

def _config_file(dataset: str, rate: str, dataset_rate_hz: float, folder: Path) -> Path:
    cfg = yaml.safe_load(default_config_path(dataset).read_text()) or {}
    runtime = dict(cfg.get("runtime") or {})
    if rate == "lockstep":
        runtime["clock"] = "lockstep"
    else:
        runtime["clock"] = "realtime"
        runtime["realtime_speed"] = float(rate) / dataset_rate_hz
    cfg["runtime"] = runtime
    path = folder / f"{dataset}-{rate}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def one_run(dataset: str, rate: str, enhance: bool, lines: bool, subscribers: int,
            max_frames: int | None) -> dict:
    source = open_source(dataset, None, max_frames=max_frames)
    row = {"size": dataset, "rate": rate, "enhance": ENHANCE_ON if enhance else "none", "lines": lines,
           "subscribers": subscribers, "dataset_rate_hz": source.rate_hz}
    spawn = mp.get_context("spawn")
    proc = None
    with tempfile.TemporaryDirectory() as tmp:
        config = _config_file(dataset, rate, source.rate_hz, Path(tmp))
        endpoint = None
        if subscribers:
            endpoint = f"tcp://127.0.0.1:{_free_port_pair()}"
            ready, done, counts = spawn.Event(), spawn.Event(), spawn.Value("q", 0)
            proc = spawn.Process(target=_subscribers_main, args=(endpoint, subscribers, ready, done, counts),
                                 daemon=True)
            proc.start()
            ready.wait(60)
        try:
            res = run_slam(dataset, config=str(config), out=str(Path(tmp) / "run"), progress=False,
                           max_frames=max_frames, enhance=row["enhance"], lines=lines, inspect=endpoint)
        finally:
            if proc is not None:
                proc.join(5)
                done.set()
                proc.join(5)
                if proc.is_alive():
                    proc.terminate()
                    proc.join(2)
                row["subscriber_messages"] = int(counts.value)
    m, stats = res.summary["metrics"], res.summary["stats"]
    t = m["tracking"]
    drops = t["frames_dropped"] + sum(int(s.get("dropped", 0)) for s in stats.values())
    wall = m["run"]["wall_s"]
    row.update({
        "ok": res.outcome.ok, "outcome": res.outcome.reason, "frames_total": t["frames_total"],
        "frames_processed": t["frames_processed"], "frames_lost": t["frames_lost"],
        "frames_not_reached": t["frames_not_reached"],
        # a frame skipped by the source, or by enhancement/tracking to keep up, has no pose
        "frames_dropped": t["frames_total"] - t["frames_processed"],
        "actor_drops": {a: int(s.get("dropped", 0)) for a, s in stats.items()}, "drop_events": drops,
        "end_to_end_ms": m.get("end_to_end_ms", {}), "wall_s": wall,
        "poses_per_s": (m.get("end_to_end_ms") or {}).get("pose_rate_hz"),
        "poses_per_wall_s": m["run"].get("frames_per_s"), "ate_rmse_m": (m.get("ate") or {}).get("rmse"),
        "actors": {a: {"service_ms": s["service_ms"], "queue_ms": s["queue_ms"], "dropped": s["dropped"],
                       "cpu_percent_mean": s["cpu_percent"]["mean"], "peak_rss_mb": s["peak_rss_mb"],
                       "messages": s["messages"]} for a, s in stats.items()},
    })
    # this process is the launcher (supervisor, collector, inspection endpoint): its RSS after the run
    row["launcher_rss_mb"] = psutil.Process().memory_info().rss / 2**20
    row["drop_fraction"] = row["frames_dropped"] / max(1, row["frames_total"])
    row["latency_bounded"] = latency_bounded(row)
    return row


def latency_bounded(row: dict) -> bool | None:
    """None in lockstep: no frame waits for a free actor there, so no queue can grow."""
    if row["rate"] == "lockstep":
        return None
    e = row.get("end_to_end_ms") or {}
    if not e.get("n"):
        return False
    period_ms = 1e3 / float(row["rate"])
    return e["last_third_p95"] <= LATENCY_GROWTH * e["first_third_p95"] + period_ms


def saturation(rows: list[dict]) -> list[dict]:
    """Per configuration: the highest realtime rate that keeps up, and the lockstep throughput."""
    out = []
    key = lambda r: (r["size"], r["enhance"], r["lines"], r["subscribers"])  # noqa: E731
    for k, group in itertools.groupby(sorted(rows, key=key), key=key):
        group = list(group)
        keeps_up = [float(r["rate"]) for r in group if r["rate"] != "lockstep" and r["ok"]
                    and r["drop_fraction"] < MAX_DROP_FRACTION and r["latency_bounded"]]
        tried = sorted(float(r["rate"]) for r in group if r["rate"] != "lockstep")
        lock = [r for r in group if r["rate"] == "lockstep"]
        out.append({"size": k[0], "enhance": k[1], "lines": k[2], "subscribers": k[3],
                    "saturation_hz": max(keeps_up) if keeps_up else None,
                    "rates_tried": tried,
                    "saturates_below_all_tried": bool(tried) and not keeps_up,
                    "lockstep_poses_per_s": lock[0]["poses_per_s"] if lock else None,
                    "first_to_saturate": _bottleneck(group)})
    return out


def _bottleneck(group: list[dict]) -> str | None:
    """The actor with the highest service p50 relative to the frame period at the lowest rate that
    dropped frames (or, if none did, the busiest actor in lockstep)."""
    dropping = [r for r in group if r["rate"] != "lockstep" and r["drop_fraction"] >= MAX_DROP_FRACTION]
    pick = min(dropping, key=lambda r: float(r["rate"])) if dropping else \
        next((r for r in group if r["rate"] == "lockstep"), None)
    if pick is None:
        return None
    busy = {a: (s["service_ms"] or {}).get("p50") or 0.0 for a, s in pick["actors"].items() if a != "source"}
    return max(busy, key=busy.get) if busy else None


# -- 0 vs N subscribers, interleaved ---------------------------------------------------------------

def compare_subscribers(pairs: int, n_subs: int, dataset: str, max_frames: int | None) -> dict:
    runs = []
    for i in range(pairs):
        for subs in (0, n_subs):  # A B A B: drift of the machine's load hits both alike
            r = one_run(dataset, "lockstep", False, False, subs, max_frames)
            runs.append({"pair": i, "subscribers": subs, "tracking_p50_ms": r["actors"]["tracking"]["service_ms"]["p50"],
                         "tracking_p95_ms": r["actors"]["tracking"]["service_ms"]["p95"],
                         "end_to_end_p50_ms": r["end_to_end_ms"].get("p50"), "poses_per_s": r["poses_per_s"],
                         "subscriber_messages": r.get("subscriber_messages"), "ok": r["ok"]})
            print(f"  compare pair {i} subs {subs:2d}: tracking p50 {runs[-1]['tracking_p50_ms']:.1f} ms",
                  file=sys.stderr)
    changes = []
    for i in range(pairs):
        a = next(r for r in runs if r["pair"] == i and r["subscribers"] == 0)["tracking_p50_ms"]
        b = next(r for r in runs if r["pair"] == i and r["subscribers"] == n_subs)["tracking_p50_ms"]
        changes.append(100.0 * (b - a) / a)
    return {"dataset": dataset, "clock": "lockstep", "subscribers": n_subs, "pairs": pairs, "runs": runs,
            "tracking_p50_change_percent_per_pair": changes,
            "tracking_p50_change_percent_median": statistics.median(changes),
            "target_percent": 5.0}


# -- output ----------------------------------------------------------------------------------------

def _f(v, spec=".0f") -> str:
    return "-" if v is None else format(v, spec)


def print_table(rows: list[dict], sat: list[dict], comparison: dict | None) -> None:
    print(f"\nCanopy SLAM load test — {os.cpu_count()} cores, Python {platform.python_version()} "
          f"(timings on a shared machine are noisy)")
    hdr = (f"{'size':6s} {'enh':5s} {'ln':2s} {'sub':>3s} {'rate':>8s} {'frames':>7s} {'drop%':>5s} "
           f"{'e2e p50/p95/p99 ms':>19s} {'bnd':>3s} | "
           + " | ".join(f"{a[:8]:>8s} svc p50/95/99 q p95" for a in ACTORS[1:4])
           + " | CPU% enh/trk/map | RSS MB trk/map")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        e = r["end_to_end_ms"] or {}
        cells = []
        for a in ACTORS[1:4]:
            s = r["actors"].get(a, {})
            sv, q = s.get("service_ms") or {}, s.get("queue_ms") or {}
            cells.append(f"{_f(sv.get('p50')):>5s}/{_f(sv.get('p95'))}/{_f(sv.get('p99'))} {_f(q.get('p95')):>5s}"
                         .rjust(27))
        cpu = "/".join(_f(r["actors"].get(a, {}).get("cpu_percent_mean")) for a in ACTORS[1:4])
        rss = "/".join(_f(r["actors"].get(a, {}).get("peak_rss_mb")) for a in ("tracking", "local_mapping"))
        rate = r["rate"] if r["rate"] == "lockstep" else f"{r['rate']} Hz"
        print(f"{r['size']:6s} {r['enhance'][:5]:5s} {'y' if r['lines'] else 'n':2s} {r['subscribers']:>3d} "
              f"{rate:>8s} {r['frames_processed']:>3d}/{r['frames_total']:<3d} {100 * r['drop_fraction']:>5.1f} "
              f"{_f(e.get('p50')):>6s}/{_f(e.get('p95'))}/{_f(e.get('p99')):<6s} {'-' if r['latency_bounded'] is None else 'y' if r['latency_bounded'] else 'n':>3s} | "
              + " | ".join(cells) + f" | {cpu:>16s} | {rss}")
    print("\nSaturation (highest rate with < 1 % drops and bounded end-to-end latency; lockstep = ceiling)")
    for s in sat:
        hz = f"{s['saturation_hz']:.0f} Hz" if s["saturation_hz"] else \
            ("below " + f"{s['rates_tried'][0]:.0f} Hz" if s["rates_tried"] else "-")
        print(f"  {s['size']:6s} enh {s['enhance']:5s} lines {'on ' if s['lines'] else 'off'} subs {s['subscribers']:>2d}: "
              f"{hz:>9s}   lockstep {_f(s['lockstep_poses_per_s'], '.1f')} poses/s   busiest actor: "
              f"{s['first_to_saturate']}")
    if comparison:
        c = comparison
        print(f"\n{c['subscribers']} inspection subscribers vs 0 ({c['dataset']}, lockstep, {c['pairs']} interleaved "
              f"pairs): tracking p50 change per pair "
              + ", ".join(f"{x:+.1f} %" for x in c["tracking_p50_change_percent_per_pair"])
              + f"; median {c['tracking_p50_change_percent_median']:+.1f} % (target <= +5 %; noisy machine)")


def plot(rows: list[dict], path: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_lat, ax_drop) = plt.subplots(1, 2, figsize=(12, 4.5))
    key = lambda r: (r["size"], r["enhance"], r["lines"], r["subscribers"])  # noqa: E731
    for k, group in itertools.groupby(sorted(rows, key=key), key=key):
        rt = sorted((r for r in group if r["rate"] != "lockstep"), key=lambda r: float(r["rate"]))
        if not rt:
            continue
        label = f"{k[0]} enh={k[1]} lines={'on' if k[2] else 'off'} subs={k[3]}"
        x = [float(r["rate"]) for r in rt]
        line, = ax_lat.plot(x, [r["end_to_end_ms"].get("p50") for r in rt], "o-", label=label)
        ax_lat.plot(x, [r["end_to_end_ms"].get("p95") for r in rt], "--", color=line.get_color(), alpha=0.6)
        ax_drop.plot(x, [100 * r["drop_fraction"] for r in rt], "o-", color=line.get_color(), label=label)
    ax_lat.set_yscale("log")
    ax_lat.set_xlabel("frame rate offered (Hz)")
    ax_lat.set_ylabel("end-to-end latency ms (solid p50, dashed p95)")
    ax_lat.set_title("frame read -> pose published")
    ax_drop.axhline(100 * MAX_DROP_FRACTION, color="k", lw=0.8, ls=":")
    ax_drop.set_xlabel("frame rate offered (Hz)")
    ax_drop.set_ylabel("frames without a pose (%)")
    ax_drop.set_title("drops (dotted: 1 % saturation bound)")
    ax_drop.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _rate(text: str) -> str:
    if text == "lockstep":
        return text
    try:
        ok = float(text) > 0
    except ValueError:
        ok = False
    if not ok:
        raise argparse.ArgumentTypeError(f"{text!r}: a rate in Hz > 0, or lockstep")
    return f"{float(text):g}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true",
                    help="both sizes at 10, 30, 60 Hz and lockstep, no enhancement, no lines, no subscribers; "
                         "2 comparison pairs")
    ap.add_argument("--sizes", nargs="+", choices=tuple(SIZES), default=list(SIZES))
    ap.add_argument("--rates", nargs="+", type=_rate, default=list(RATES),
                    help="frame rates in Hz (any > 0, e.g. 5 on a slow machine) and/or lockstep")
    ap.add_argument("--enhance", nargs="+", choices=("off", "on"), default=["off", "on"])
    ap.add_argument("--lines", nargs="+", choices=("off", "on"), default=["off", "on"])
    ap.add_argument("--subscribers", nargs="+", type=int, default=[0, 20])
    ap.add_argument("--max-frames", type=int, default=None, help="default: the whole bundled snippet")
    ap.add_argument("--compare-pairs", type=int, default=None,
                    help="0 vs N subscribers, interleaved pairs (default 3, --quick 2; 0 skips)")
    ap.add_argument("--compare-subscribers", type=int, default=20)
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "bench_load.json"))
    ap.add_argument("--plot", default=str(ROOT / "docs" / "results" / "bench_load.png"))
    args = ap.parse_args()
    if args.quick:
        args.rates, args.enhance, args.lines, args.subscribers = ["10", "30", "60", "lockstep"], ["off"], ["off"], [0]
    pairs = args.compare_pairs if args.compare_pairs is not None else (2 if args.quick else 3)
    grid = list(itertools.product(args.sizes, args.enhance, args.lines, args.subscribers, args.rates))
    rows = []
    t_all = time.monotonic()
    for i, (size, enh, lines, subs, rate) in enumerate(grid, 1):
        t0 = time.monotonic()
        rows.append(one_run(size, rate, enh == "on", lines == "on", subs, args.max_frames))
        r = rows[-1]
        print(f"  [{i}/{len(grid)}] {size} enh={enh} lines={lines} subs={subs} rate={rate}: "
              f"{r['frames_processed']}/{r['frames_total']} poses, e2e p50 {_f(r['end_to_end_ms'].get('p50'))} ms "
              f"({time.monotonic() - t0:.0f} s)", file=sys.stderr)
    comparison = compare_subscribers(pairs, args.compare_subscribers, "euroc", args.max_frames) if pairs else None
    sat = saturation(rows)
    print_table(rows, sat, comparison)
    png = plot(rows, Path(args.plot)) if rows else None
    command = "python benchmarks/bench_load.py " + " ".join(sys.argv[1:])
    out = write_json(args.out, {"command": command.strip(), "mode": "quick" if args.quick else "grid",
                                "cpu_count": os.cpu_count(), "machine": platform.platform(),
                                "note": "timings measured on a machine shared with other jobs: noisy",
                                "time": time.strftime("%Y-%m-%d %H:%M:%S"), "wall_s": time.monotonic() - t_all,
                                "saturation_rule": {"max_drop_fraction": MAX_DROP_FRACTION,
                                                    "latency_growth": LATENCY_GROWTH},
                                "rows": rows, "saturation": sat, "subscriber_comparison": comparison,
                                "plot": str(png) if png else None})
    print(f"\nwrote {out}" + (f" and {png}" if png else ""))
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
