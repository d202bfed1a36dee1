#!/usr/bin/env python
"""Issue 9's criteria over several noise draws of the degradation grid, as Markdown.

One grid run decides each cell on one draw of the sensor noise (``bench_degrade_grid.py --seed``), and on the
dim noisy cells one draw says little: s29 measured the day-loop's 15 % light cell passing the bar on 3 of 7
draws while the grid's seed 0 counts it a pass (docs/notes/s29-scale.md). This table puts the draws side by
side: per (dataset, cell), Canopy ``auto``'s ATE on each draw, the bar (1.5x the clean ``auto`` ATE of the
reference run) and on how many draws each criterion holds (``bench_degrade_grid.issue9_checks``).

The reference run supplies the clean rows and ORB-SLAM3's rows (typically the shipped grid,
``docs/results/bench_degrade_grid.json``); each draw supplies its degraded rows (a run with ``--skip-clean``),
which replace the reference's: its ``auto`` rows, and its ORB-SLAM3 rows where it ran ORB-SLAM3 on that draw
(``--peers raw``). Where it did not, ORB-SLAM3's row is the reference run's, another draw; the table marks
those verdicts with ``*``. A cell without ORB-SLAM3 beside it in either is left out.

    python benchmarks/grid_draws.py --reference docs/results/bench_degrade_grid.json \\
        0=/tmp/g0/bench_degrade_grid.json 1=/tmp/g1/bench_degrade_grid.json 2=/tmp/g2/bench_degrade_grid.json
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_degrade_grid import ATE_FACTOR, issue9_checks  # noqa: E402
from benchmarks.grid_table import _mm, _pct  # noqa: E402
from shared.errors import InputError  # noqa: E402

PEER = "orbslam3-raw"   # the peer the criteria compare with (bench_degrade_grid.issue9_checks)


def _rows(path: Path) -> list[dict]:
    try:
        data = json.loads(Path(path).read_text())
        rows = data["rows"]
    except FileNotFoundError:
        raise InputError(path, "no such bench_degrade_grid JSON") from None
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise InputError(path, f"not a bench_degrade_grid JSON ({type(exc).__name__}: {exc})") from None
    return rows


def parse_draw(text: str) -> tuple[str, Path]:
    """``SEED=PATH`` -> (seed label, path)."""
    seed, sep, path = text.partition("=")
    if not sep or not seed or not path:
        raise InputError(text, "a draw is SEED=PATH, e.g. 3=/tmp/g3/bench_degrade_grid.json")
    return seed, Path(path)


def draw_verdicts(reference: list[dict], draws: dict[str, list[dict]]) -> dict:
    """{(dataset, cell): {"ate": {seed: m | None}, "tracked": {seed: %}, "pass": {seed: bool | None},
    "peer": {seed: bool}, "peer_other_draw": {seeds judged against the reference's ORB-SLAM3 row}, "bar_m": m | None}}
    for every degraded cell a draw ran with ORB-SLAM3 beside it (the draw's own run or the reference's)."""
    out: dict = {}
    for seed, rows in draws.items():
        latest = {(r["dataset"], r["cell"], r["method"]): r for r in reference}
        mine = {(r["dataset"], r["cell"]) for r in rows if r["method"] == "auto" and r["cell"] != "clean"}
        own_peer = {(r["dataset"], r["cell"]) for r in rows if r["method"] == PEER}
        for r in rows:
            if r["cell"] != "clean":
                latest[(r["dataset"], r["cell"], r["method"])] = r
        merged = list(latest.values())
        for c in issue9_checks(merged):
            key = (c["dataset"], c["cell"])
            if key not in mine:
                continue
            auto = latest[(c["dataset"], c["cell"], "auto")]
            clean = (latest.get((c["dataset"], "clean", "auto")) or {}).get("ate_rmse_m")
            cell = out.setdefault(key, {"ate": {}, "tracked": {}, "pass": {}, "peer": {}, "peer_other_draw": set(),
                                        "bar_m": None if clean is None else ATE_FACTOR * clean})
            if key not in own_peer:
                cell["peer_other_draw"].add(seed)
            cell["ate"][seed] = auto.get("ate_rmse_m")
            cell["tracked"][seed] = auto.get("tracked_pct") or 0.0
            cell["pass"][seed] = c["pass"]
            cell["peer"][seed] = c["at_least_orb_raw"]
    return out


def table(verdicts: dict, seeds: list[str]) -> str:
    out = ["| dataset | cell | Canopy auto ATE mm, seeds " + " / ".join(seeds)
           + f" | bar ({ATE_FACTOR}x clean) | bar passed | ≥ ORB-SLAM3 raw |", "|---|---|---|---|---|---|"]
    for (d, cell), v in verdicts.items():
        ates = []
        for s in seeds:
            if s not in v["ate"]:
                ates.append("·")
                continue
            trk = v["tracked"][s]
            ates.append(_mm(v["ate"][s]) + ("" if trk >= 100.0 else f" ({_pct(trk)} %)"))
        passes = [p for p in v["pass"].values() if p is not None]
        bar = "n/a (ORB < 50 %)" if not passes else f"{sum(passes)} of {len(passes)}"
        peer = f"{sum(v['peer'].values())} of {len(v['peer'])}"
        if v["peer_other_draw"]:
            peer += "*"
        out.append(f"| {d} | {cell} | {' / '.join(ates)} | {_mm(v['bar_m'])} | {bar} | {peer} |")
    if any(v["peer_other_draw"] for v in verdicts.values()):
        out.append("")
        out.append("\\* some draws judged against ORB-SLAM3 on the reference run's draw (ORB-SLAM3 not run on theirs)")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reference", default=str(ROOT / "docs" / "results" / "bench_degrade_grid.json"),
                    help="the grid run with the clean rows and ORB-SLAM3's rows")
    ap.add_argument("draws", nargs="+", help="SEED=bench_degrade_grid.json of one draw")
    args = ap.parse_args(argv)
    try:
        reference = _rows(Path(args.reference))
        draws = {seed: _rows(path) for seed, path in map(parse_draw, args.draws)}
    except InputError as exc:
        print(f"grid_draws: {exc}", file=sys.stderr)
        return 2
    print(table(draw_verdicts(reference, draws), list(draws)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
