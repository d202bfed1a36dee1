#!/usr/bin/env python
"""Watch a running Canopy SLAM session from another terminal or machine.

    python launch.py --dataset kitti --inspect tcp://127.0.0.1:5560        # loopback: no keys
    python tools/watch_run.py tcp://127.0.0.1:5560

    # across machines, with keys from tools/make_inspect_keys.py:
    python launch.py --inspect tcp://0.0.0.0:5560 --inspect-keys keys/
    python tools/watch_run.py tcp://robot:5560 --client-key laptop.key_secret --server-key server.key

Says which run it watches (run id, dataset, from the run's status or its run_start event),
prints one line per tracked frame and a per-actor line whenever an actor reports its stats (once
a second), and exits when the run ends (exit code 0 if the run completed, 1 if it ended early,
2 if no run answered). ``--json`` prints one JSON object per event instead, for scripts.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from actors.inspection import inspection_client, inspection_request, load_client_keys  # noqa: E402
from canopy.report import to_jsonable  # noqa: E402
from protocol.messages import (  # noqa: E402
    ActorError, ActorStats, FramePose, LoopResult, MapDelta, MapSaved, MapSnapshot, RunEnd, RunStart,
)


def describe(msg) -> str | None:
    """One human line per event (None: not shown)."""
    if isinstance(msg, RunStart):
        return (f"run   {msg.run_id}  dataset {msg.dataset} ({msg.source})  {msg.n_frames} frames  "
                f"clock {msg.clock}")
    if isinstance(msg, RunEnd):
        return f"end   {msg.run_id}  {'completed' if msg.ok else 'ended early'}: {msg.reason}  ({msg.wall_s:.1f} s)"
    if isinstance(msg, FramePose):
        t = msg.T_world_cam[:3, 3]
        where = (f"xyz {t[0]:8.3f} {t[1]:8.3f} {t[2]:8.3f}" if msg.status in ("init", "ok")
                 else f"no pose ({msg.lost_reason or 'lost'})")
        return (f"pose  #{msg.index:5d} {msg.status:4s} inliers {msg.n_inliers:4d} {where}"
                f"{'  KF' if msg.is_keyframe else ''}")
    if isinstance(msg, ActorStats) and len(msg.service_ms):
        svc = sorted(float(x) for x in msg.service_ms)
        return (f"stats {msg.actor:14s} msgs {msg.messages:6d} drop {msg.dropped:4d} "
                f"svc p50 {svc[len(svc) // 2]:6.1f} ms p95 {svc[min(len(svc) - 1, int(0.95 * len(svc)))]:6.1f} ms "
                f"cpu {msg.cpu_percent:5.1f}% rss {msg.rss_mb:6.0f} MB")
    if isinstance(msg, MapSnapshot):
        return f"map   {len(msg.keyframe_indices)} keyframes, {len(msg.points)} points, {len(msg.lines)} lines"
    if isinstance(msg, MapDelta):
        return (f"map   {len(msg.keyframe_indices)} keyframes, {msg.n_points} points "
                f"(+{len(msg.point_ids)} new or moved, -{len(msg.removed_ids)} removed)")
    if isinstance(msg, LoopResult) and msg.closed:
        return f"loop  keyframe {msg.keyframe_index} <-> {msg.candidate}  {msg.n_inliers} inliers  ({msg.loops} closed)"
    if isinstance(msg, MapSaved):
        return (f"saved map {msg.path}: {msg.keyframes} keyframes, {msg.points} points" if msg.ok
                else f"ERROR saving map {msg.path}: {msg.error}")
    if isinstance(msg, ActorError):
        return f"ERROR {msg.actor}: {msg.error}"
    return None


def as_json(msg) -> str:
    body = {k: v for k, v in vars(msg).items() if k not in ("service_ms", "queue_ms", "points", "lines",
                                                           "keyframe_poses", "keyframe_stamps", "positions",
                                                           "point_ids", "removed_ids", "jpeg", "corrections")}
    return json.dumps(to_jsonable({"kind": msg.KIND, **body}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("endpoint", help="the --inspect endpoint of a running launch.py")
    ap.add_argument("--kinds", nargs="*", default=None,
                    help="message kinds to show (pose stats map_delta loop_result actor_error ...); default all")
    ap.add_argument("--timeout", type=float, default=30.0, help="give up after this many silent seconds")
    ap.add_argument("--json", action="store_true", help="one JSON object per event")
    ap.add_argument("--client-key", help="this client's CURVE secret key file (for a non-loopback run)")
    ap.add_argument("--server-key", help="the launcher's public key file server.key")
    args = ap.parse_args(argv)
    if bool(args.client_key) != bool(args.server_key):
        print("error: --client-key and --server-key go together", file=sys.stderr)
        return 2
    keys = load_client_keys(args.client_key, args.server_key) if args.client_key else None
    emit = (lambda m: print(as_json(m), flush=True)) if args.json else None

    status = inspection_request(args.endpoint, "status", timeout_s=min(args.timeout, 5.0), keys=keys)
    if status is not None and status.ok:
        p = status.payload
        if emit:
            print(json.dumps(to_jsonable({"kind": "status", "run_id": status.run_id, **p})), flush=True)
        else:
            print(f"run   {status.run_id}  dataset {p.get('dataset')} ({p.get('source')})  "
                  f"frame {p.get('frames_done')}/{p.get('frames_total')}", flush=True)
    kinds = None if args.kinds is None else [*args.kinds, "run_start"]
    ended = None
    for msg in inspection_client(args.endpoint, kinds, args.timeout, keys=keys, until_run_end=True):
        if emit:
            emit(msg)
        else:
            line = describe(msg)
            if line:
                print(line, flush=True)
        if isinstance(msg, RunEnd):
            ended = msg
    if ended is None:
        print(f"error: no run end seen on {args.endpoint} ({args.timeout:g} s of silence)", file=sys.stderr)
        return 2
    return 0 if ended.ok else 1


if __name__ == "__main__":
    sys.exit(main())
