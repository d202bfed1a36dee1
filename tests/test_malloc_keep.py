"""runtime.malloc_keep_mb (actors.runtime.keep_freed_memory): a freed block below the threshold is
reused without page faults; glibc's default maps a fresh one. Measured in fresh interpreters (the
thresholds are process-wide), on the process's own minor-fault counter."""
import subprocess
import sys

import pytest

from canopy.config import load_run_config, with_settings
from shared.errors import ConfigError

_PROBE = r"""
import resource, sys
import numpy as np
from actors.runtime import keep_freed_memory
keep = int(sys.argv[1])
assert keep_freed_memory(keep) == (keep > 0)
n = 8 << 20
a = np.ones(n, np.uint8); del a            # first 8 MB block, touched, freed
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
b = np.ones(n, np.uint8); del b            # the second one: reused pages or fresh ones?
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(keep_mb: int) -> int:
    out = subprocess.run([sys.executable, "-c", _PROBE, str(keep_mb)], capture_output=True, text=True, check=True)
    return int(out.stdout.strip())


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallopt")
def test_kept_block_is_reused_without_page_faults():
    # glibc's default: the freed 8 MB went back to the kernel and the second block faults in again
    # (~490 faults here, not 2048: numpy asks for huge pages on large arrays)
    assert _faults(0) > 100
    assert _faults(32) < 20    # kept: the second block reuses the first one's pages


def test_malloc_keep_out_of_range_names_the_setting():
    with pytest.raises(ConfigError, match="runtime.malloc_keep_mb"):
        with_settings(load_run_config("euroc"), [("runtime", "malloc_keep_mb", 64)])
    with pytest.raises(ConfigError, match="runtime.malloc_keep_mb"):
        with_settings(load_run_config("euroc"), [("runtime", "malloc_keep_mb", -1)])
