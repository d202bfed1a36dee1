"""benchmarks/grid_draws.py: issue 9's criteria counted over several noise draws of the degradation grid."""
from __future__ import annotations

import json

import pytest

from benchmarks.grid_draws import draw_verdicts, main, parse_draw, table
from shared.errors import InputError


def _row(cell, method, ate, tracked=100.0, dataset="day-loop"):
    return {"dataset": dataset, "cell": cell, "method": method, "ate_rmse_m": ate, "tracked_pct": tracked}


REFERENCE = [_row("clean", "auto", 0.010),
             _row("g0.15-b0-high", "auto", 0.011), _row("g0.15-b0-high", "orbslam3-raw", 0.020),
             _row("g0.06-b0-high", "auto", 0.030), _row("g0.06-b0-high", "orbslam3-raw", None, tracked=10.0),
             _row("g0.02-b0-high", "auto", 0.500)]          # no ORB-SLAM3 beside it: no verdict


def test_each_draw_is_judged_against_the_reference_clean_run_and_peer():
    draws = {"0": [_row("g0.15-b0-high", "auto", 0.012), _row("g0.06-b0-high", "auto", 0.040)],
             "1": [_row("g0.15-b0-high", "auto", 0.016)],                  # over the bar 15 mm
             "2": [_row("g0.15-b0-high", "auto", 0.025, tracked=98.0),     # loses to ORB-SLAM3's 20 mm too
                   _row("g0.02-b0-high", "auto", 0.400)]}
    v = draw_verdicts(REFERENCE, draws)
    lit = v[("day-loop", "g0.15-b0-high")]
    assert lit["bar_m"] == pytest.approx(0.015)
    assert lit["pass"] == {"0": True, "1": False, "2": False}
    assert lit["peer"] == {"0": True, "1": True, "2": False}
    dark = v[("day-loop", "g0.06-b0-high")]
    assert dark["pass"] == {"0": None} and dark["peer"] == {"0": True}   # ORB-SLAM3 tracks < half: no bar
    assert ("day-loop", "g0.02-b0-high") not in v
    text = table(v, ["0", "1", "2"])
    assert "| day-loop | g0.15-b0-high | 12.0 / 16.0 / 25.0 (98 %) | 15.0 | 1 of 3 | 2 of 3* |" in text
    assert "| day-loop | g0.06-b0-high | 40.0 / · / · | 15.0 | n/a (ORB < 50 %) | 1 of 1* |" in text
    assert "ORB-SLAM3 not run on theirs" in text


def test_a_draw_with_its_own_orbslam3_run_is_judged_against_it():
    """16 mm loses to the reference draw's ORB-SLAM3 (20 mm would not; 14 mm does) only on the draw where
    ORB-SLAM3 itself ran at 14 mm; the reference's 20 mm stands in for the draw without a peer run."""
    draws = {"3": [_row("g0.15-b0-high", "auto", 0.016), _row("g0.15-b0-high", "orbslam3-raw", 0.014)],
             "4": [_row("g0.15-b0-high", "auto", 0.016)]}
    v = draw_verdicts(REFERENCE, draws)[("day-loop", "g0.15-b0-high")]
    assert v["peer"] == {"3": False, "4": True}
    assert v["peer_other_draw"] == {"4"}
    v = draw_verdicts(REFERENCE, {"3": draws["3"]})
    assert "| 0 of 1 |" in table(v, ["3"]) and "not run on theirs" not in table(v, ["3"])


def test_bad_arguments_name_the_input(tmp_path, capsys):
    with pytest.raises(InputError, match="SEED=PATH"):
        parse_draw("/tmp/g3/bench_degrade_grid.json")
    ref = tmp_path / "ref.json"
    ref.write_text(json.dumps({"rows": REFERENCE}))
    broken = tmp_path / "draw.json"
    broken.write_text("{not json")
    assert main(["--reference", str(ref), f"3={broken}"]) == 2
    assert "draw.json: not a bench_degrade_grid JSON" in capsys.readouterr().err
    assert main(["--reference", str(tmp_path / "missing.json"), f"3={broken}"]) == 2
    assert "missing.json: no such bench_degrade_grid JSON" in capsys.readouterr().err
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"rows": [_row("g0.15-b0-high", "auto", 0.012)]}))
    assert main(["--reference", str(ref), f"7={good}"]) == 0
    assert "| day-loop | g0.15-b0-high | 12.0 | 15.0 | 1 of 1 | 1 of 1* |" in capsys.readouterr().out
