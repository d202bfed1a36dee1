"""benchmarks/bench_degrade_grid.py (same arguments) with local BA switched off when NOBA=1 (probe of
docs/notes/s14-jitter.md: keyframes inserted and their landmarks created, nothing refined by local mapping).
Throw-away measurement script, run from the worktree root."""
import os, runpy, sys
sys.path.insert(0, os.getcwd())
import canopy.backend.local_ba as lb
if os.environ.get("NOBA"):
    lb.LocalBundleAdjustmentMixin._bundle_adjust = lambda self, *a, **k: None
sys.argv = ["bench_degrade_grid.py"] + sys.argv[1:]
runpy.run_path("benchmarks/bench_degrade_grid.py", run_name="__main__")
