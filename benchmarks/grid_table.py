#!/usr/bin/env python
"""Issue 9's per-cell table of one or more ``bench_degrade_grid.py`` outputs, as Markdown.

One line per (dataset, cell): Canopy ``none`` and ``auto`` (tracked %, ATE mm), ORB-SLAM3 on raw
frames (the median run ``median_run`` picked, and the range of tracked % and ATE over its runs), the
bar (1.5x the clean ``auto`` ATE) and the two criteria as ``bench_degrade_grid.issue9_checks``
decides them: the bar (only where ORB-SLAM3 raw tracks >= half the frames) and "at least ORB-SLAM3
raw". Reads finished JSONs and the ``bench_degrade_grid.partial.json`` of a run stopped early (its
rows so far): a cell without its ``auto`` or ORB-SLAM3 row is listed, its verdicts "-".

    python benchmarks/grid_table.py /tmp/heldout/kitti_euroc/bench_degrade_grid.json [more.json ...]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_degrade_grid import ATE_FACTOR, issue9_checks  # noqa: E402


def load_rows(paths) -> list[dict]:
    """Every row of the files; a later file's row replaces an earlier one of the same dataset, cell
    and method (as ``bench_degrade_grid.merge``)."""
    latest = {}
    for p in paths:
        for r in json.loads(Path(p).read_text())["rows"]:
            latest[(r["dataset"], r["cell"], r["method"])] = r
    return list(latest.values())


def _mm(ate) -> str:
    return "-" if ate is None else f"{1000.0 * ate:.1f}"


def _pct(v) -> str:
    """Tracked %: whole numbers as such, 299 of 300 frames as 99.7, never rounded up to 100."""
    v = v or 0.0
    return f"{v:.0f}" if abs(v - round(v)) < 1e-6 else f"{v:.1f}"


def _canopy(r) -> str:
    if r is None:
        return "not run"
    return f"{_pct(r.get('tracked_pct'))} % / {_mm(r.get('ate_rmse_m'))}"


def _peer(r) -> str:
    if r is None:
        return "not run"
    runs = r.get("runs") or [r]
    trk = [x.get("tracked_pct") or 0.0 for x in runs]
    ates = [x["ate_rmse_m"] for x in runs if x.get("ate_rmse_m") is not None]
    span = f"{_pct(min(trk))}–{_pct(max(trk))} %" if min(trk) != max(trk) else f"{_pct(trk[0])} %"
    ate_span = "-" if not ates else (_mm(min(ates)) if len(ates) == 1 else f"{_mm(min(ates))}–{_mm(max(ates))}")
    return f"{_pct(r.get('tracked_pct'))} % / {_mm(r.get('ate_rmse_m'))} ({span}; {ate_span})"


def table(rows: list[dict]) -> str:
    """The Markdown table (ATE in mm) and one summary line per dataset."""
    def row(d, cell, method):
        return next((r for r in rows if r["dataset"] == d and r["cell"] == cell and r["method"] == method), None)

    checks = {(c["dataset"], c["cell"]): c for c in issue9_checks(rows)}
    out = ["| dataset | cell | Canopy none: tracked / ATE mm | Canopy auto | ORB-SLAM3 raw median (runs' range) "
           f"| bar ({ATE_FACTOR}x clean auto) | bar | ≥ ORB-SLAM3 raw |",
           "|---|---|---|---|---|---|---|---|"]
    summary = []
    for d in dict.fromkeys(r["dataset"] for r in rows):
        clean = (row(d, "clean", "auto") or {}).get("ate_rmse_m")
        bar = None if clean is None else ATE_FACTOR * clean
        for cell in dict.fromkeys(r["cell"] for r in rows if r["dataset"] == d):
            c = checks.get((d, cell))
            verdict_bar = "-" if c is None else ("n/a (ORB < 50 %)" if c["pass"] is None
                                                 else ("pass" if c["pass"] else "**FAIL**"))
            verdict_peer = "-" if c is None else ("yes" if c["at_least_orb_raw"] else "**no**")
            out.append(f"| {d} | {cell} | {_canopy(row(d, cell, 'none'))} | {_canopy(row(d, cell, 'auto'))} | "
                       f"{_peer(row(d, cell, 'orbslam3-raw'))} | {_mm(bar) if cell != 'clean' else '-'} | "
                       f"{verdict_bar if cell != 'clean' else ''} | {verdict_peer if cell != 'clean' else ''} |")
        mine = [c for c in checks.values() if c["dataset"] == d]
        on_bar = [c for c in mine if c["orb_raw_tracks_half"]]
        summary.append(f"{d}: bar {sum(c['pass'] for c in on_bar)}/{len(on_bar)}, at least ORB-SLAM3 raw "
                       f"{sum(c['at_least_orb_raw'] for c in mine)}/{len(mine)}")
    return "\n".join(out + [""] + summary)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json", nargs="+", help="bench_degrade_grid.json (or .partial.json) files")
    args = ap.parse_args(argv)
    print(table(load_rows(args.json)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
