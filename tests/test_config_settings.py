"""``section.field=value`` settings as the benchmarks take them (canopy.config.parse_setting / with_settings)."""
import pytest

from canopy.config import load_run_config, parse_setting, parse_variant, with_settings
from shared.errors import ConfigError


def test_settings_parse_and_apply_to_typed_sections():
    assert parse_setting("tracking.n_features=1600") == ("tracking", "n_features", 1600)
    assert parse_setting("tracking.parallel_extraction=false") == ("tracking", "parallel_extraction", False)
    assert parse_setting("enhancement.method=afe") == ("enhancement", "method", "afe")
    name, sets = parse_variant("before:runtime.map_update_lag_frames=0,tracking.n_features=2000")
    assert name == "before" and sets == [("runtime", "map_update_lag_frames", 0), ("tracking", "n_features", 2000)]
    cfg = with_settings(load_run_config("kitti"), sets)
    assert cfg.runtime.map_update_lag_frames == 0 and cfg.tracking.n_features == 2000
    assert load_run_config("kitti").runtime.map_update_lag_frames == 1  # the shipped config is untouched


def test_bad_settings_name_the_setting():
    cfg = load_run_config("euroc")
    with pytest.raises(ConfigError, match="section.field=value"):
        parse_setting("n_features=1600")
    with pytest.raises(ConfigError, match="tracking.n_feature"):
        with_settings(cfg, [("tracking", "n_feature", 1600)])
    with pytest.raises(ConfigError, match="nosuch.x"):
        with_settings(cfg, [("nosuch", "x", 1)])
    with pytest.raises(ConfigError, match="map_update_lag_frames"):  # the section re-validates
        with_settings(cfg, [("runtime", "map_update_lag_frames", 99)])
