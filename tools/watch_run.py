#!/usr/bin/env python
"""Watch a running Canopy SLAM session from another machine.

    python launch.py --dataset kitti --inspect tcp://0.0.0.0:5560      # on the robot
    python tools/watch_run.py tcp://robot:5560                             # anywhere

Prints one line per tracked frame and a per-actor latency line every time an
actor reports its stats (once a second).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from actors.supervisor import inspection_client  # noqa: E402
from protocol.messages import ActorError, ActorStats, FramePose, MapSnapshot  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("endpoint", help="the --inspect endpoint of a running launch.py")
    ap.add_argument("--kinds", nargs="*", default=None,
                    help="message kinds to show (pose stats map_snapshot actor_error ...); default all")
    ap.add_argument("--timeout", type=float, default=30.0, help="give up after this many silent seconds")
    args = ap.parse_args()
    for msg in inspection_client(args.endpoint, args.kinds, args.timeout):
        if isinstance(msg, FramePose):
            t = msg.T_world_cam[:3, 3]
            print(f"pose  #{msg.index:5d} {msg.status:4s} inliers {msg.n_inliers:4d} "
                  f"xyz {t[0]:8.3f} {t[1]:8.3f} {t[2]:8.3f}{'  KF' if msg.is_keyframe else ''}")
        elif isinstance(msg, ActorStats) and len(msg.service_ms):
            print(f"stats {msg.actor:14s} msgs {msg.messages:6d} drop {msg.dropped:4d} "
                  f"svc p50 {float(sorted(msg.service_ms)[len(msg.service_ms) // 2]):6.1f} ms "
                  f"cpu {msg.cpu_percent:5.1f}% rss {msg.rss_mb:6.0f} MB")
        elif isinstance(msg, MapSnapshot):
            print(f"map   {len(msg.keyframe_indices)} keyframes, {len(msg.points)} points")
        elif isinstance(msg, ActorError):
            print(f"ERROR {msg.actor}: {msg.error}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
