"""Actors run at the CPU priority their config asks for (runtime.feeder_niceness, runtime.mapping_niceness)
and with the malloc thresholds it sets (runtime.malloc_keep_mb):
read back from each process as it ran (stats.json), on a short real EuRoC run."""
import json

import pytest

from canopy.config import load_run_config, with_settings
from shared.errors import ConfigError


def test_local_mapping_and_feeders_run_at_their_configured_niceness(tmp_path):
    from canopy.app import run_slam

    cfg = load_run_config("euroc")
    res = run_slam("euroc", max_frames=6, clock="lockstep", out=str(tmp_path / "run"), progress=False, loop=False)
    assert res.outcome.ok, res.outcome.reason
    stats = json.loads((tmp_path / "run" / "stats.json").read_text())
    nice = {name: s["extra"]["niceness"] for name, s in stats.items()}
    assert nice["local_mapping"] == cfg.runtime.mapping_niceness > 0  # euroc.yaml lowers local mapping
    assert nice["source"] == nice["enhancement"] == cfg.runtime.feeder_niceness
    assert nice["tracking"] == 0  # the critical path keeps its priority
    # ... and every actor kept its freed heap as runtime.malloc_keep_mb asks (glibc: mallopt succeeded)
    assert {name: s["extra"]["malloc_keep_mb"] for name, s in stats.items()} == \
        {name: cfg.runtime.malloc_keep_mb for name in stats} and cfg.runtime.malloc_keep_mb > 0


def test_mapping_niceness_out_of_range_names_the_setting():
    with pytest.raises(ConfigError, match="runtime.mapping_niceness"):
        with_settings(load_run_config("euroc"), [("runtime", "mapping_niceness", 20)])
