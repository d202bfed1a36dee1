"""Issue 9's per-cell Markdown table of the degradation grid (benchmarks/grid_table.py)."""
import json

from benchmarks.grid_table import load_rows, table


def _row(cell, method, tracked, ate, runs=None):
    r = {"dataset": "kitti", "cell": cell, "method": method, "tracked_pct": tracked, "ate_rmse_m": ate}
    if runs is not None:
        r["runs"] = [{"tracked_pct": t, "ate_rmse_m": a} for t, a in runs]
    return r


def _line(text, cell):
    return next(line for line in text.splitlines() if f"| {cell} |" in line)


def test_table_gives_both_verdicts_the_bar_and_the_peer_range():
    rows = [_row("clean", "none", 100.0, 0.04), _row("clean", "auto", 100.0, 0.04),
            _row("lit", "none", 100.0, 0.05), _row("lit", "auto", 100.0, 0.055),
            _row("lit", "orbslam3-raw", 100.0, 0.08, runs=[(100.0, 0.08), (100.0, 0.06), (100.0, 0.11)]),
            _row("hazy", "auto", 100.0, 0.20), _row("hazy", "orbslam3-raw", 100.0, 0.05),
            _row("dark", "auto", 100.0, 0.06),
            _row("dark", "orbslam3-raw", 100.0 * 3 / 51, 0.004, runs=[(100.0 * 3 / 51, 0.004)] * 3),
            _row("stopped", "none", 100.0, 0.05)]  # a run stopped before this cell's auto row
    text = table(rows)
    lit = _line(text, "lit")
    assert "100 % / 50.0" in lit and "100 % / 55.0" in lit  # none, auto
    assert "100 % / 80.0 (100 %; 60.0–110.0)" in lit  # the median run and the runs' ATE range
    assert "| 60.0 | pass | yes |" in lit  # bar 1.5 x 40 mm
    assert "| **FAIL** | **no** |" in _line(text, "hazy")  # 5x clean and worse than ORB-SLAM3
    dark = _line(text, "dark")
    assert "5.9 % / 4.0" in dark  # 3 of 51 frames: one decimal, not rounded to 6
    assert "n/a (ORB < 50 %) | yes |" in dark  # a 3-frame ATE is not compared with a 51-frame one
    assert "not run" in _line(text, "stopped") and _line(text, "stopped").endswith("| - | - |")
    assert "kitti: bar 1/2, at least ORB-SLAM3 raw 2/3" in text


def test_later_files_replace_rows_of_the_same_cell(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps({"rows": [_row("clean", "auto", 100.0, 0.04), _row("lit", "auto", 50.0, None)]}))
    b.write_text(json.dumps({"rows": [_row("lit", "auto", 100.0, 0.05)]}))
    rows = load_rows([a, b])
    assert len(rows) == 2
    assert next(r for r in rows if r["cell"] == "lit")["tracked_pct"] == 100.0
