#!/usr/bin/env python
"""CPU ms per frame per actor thread (stats.json ``threads``), the ORB stages' CPU p50
(``stage_ms_p50``), ATE and whether trajectory.tum is byte-identical, for launch.py output folders
given as base/branch pairs (s15-extract).

    python docs/results/s15_extract/actor_cpu.py /tmp/s15x/lb1:/tmp/s15x/ln1 /tmp/s15x/lb2:/tmp/s15x/ln2
"""
from __future__ import annotations

import json
import sys
from pathlib import Path


def summary(out: Path) -> dict:
    s = json.loads((out / "stats.json").read_text())
    m = json.loads((out / "metrics.json").read_text())
    row = {}
    for actor in ("source", "tracking", "local_mapping"):
        th = (s.get(actor, {}).get("extra", {}) or {}).get("threads") or {}
        for name, t in th.items():
            row[f"{actor}.{name}"] = t.get("cpu_ms_per_frame")
    st = s["tracking"]["extra"].get("stage_ms_p50", {})
    for k in ("orb", "orb_right", "stereo_pyramids", "stereo_worker", "track_local_map", "total"):
        row["stage p50 " + k] = st.get(k)
    row["service_ms p50"] = (s["tracking"].get("service_ms") or {}).get("p50")
    row["ATE rmse m"] = m["ate"]["rmse"]
    row["frames/s (tracked span)"] = None
    ex = s["tracking"]["extra"]
    if ex.get("first_frame_done_at") and ex.get("last_frame_done_at"):
        n = m["tracking"]["frames_processed"]
        row["frames/s (tracked span)"] = (n - 1) / (ex["last_frame_done_at"] - ex["first_frame_done_at"])
    return row


def main() -> None:
    for pair in sys.argv[1:]:
        a, b = (Path(p) for p in pair.split(":"))
        ra, rb = summary(a), summary(b)
        same = (a / "trajectory.tum").read_bytes() == (b / "trajectory.tum").read_bytes()
        print(f"{a.name} -> {b.name}: trajectory.tum byte-identical: {same}")
        for k in ra:
            va, vb = ra[k], rb.get(k)
            fa = f"{va:.2f}" if isinstance(va, (int, float)) else str(va)
            fb = f"{vb:.2f}" if isinstance(vb, (int, float)) else str(vb)
            print(f"  {k:34s} {fa:>9s} -> {fb:>9s}")


if __name__ == "__main__":
    main()
