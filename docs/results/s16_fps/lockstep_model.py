"""What lockstep throughput the actors' CPU allows on a dedicated 2-core machine (s16-fps).

The model itself now lives in ``docs/results/s17_fps/lockstep_service.py`` (s17-fps extended it with the
tracking actor's service time); this runs it with s16's variants, so the s16 note's commands still work:

    python docs/results/s16_fps/lockstep_model.py --reps 2 --out docs/results/s16_fps/lockstep_model.json
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

_PATH = Path(__file__).resolve().parents[1] / "s17_fps" / "lockstep_service.py"
_spec = importlib.util.spec_from_file_location("lockstep_service", _PATH)
model = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(model)

S16_VARIANTS = {  # s16-fps's variants (name: simulate() keyword arguments)
    "before": {"order": "before"},
    "ahead": {"order": "ahead"},
    "before_mapping_nice5": {"order": "before", "mapping_nice": 5},
    "ahead_mapping_nice5": {"order": "ahead", "mapping_nice": 5},
    "ahead_worker_nice5": {"order": "ahead", "worker_nice": 5},
    "ahead_prefetch1": {"order": "ahead", "prefetch": 1},
    "ahead_feeders_nice0": {"order": "ahead", "feeder_nice": 0},
    "before_lag2": {"order": "before", "lag": 2},
    "ahead_lag2": {"order": "ahead", "lag": 2},
}

model.VARIANTS = S16_VARIANTS

if __name__ == "__main__":
    sys.exit(model.main())
