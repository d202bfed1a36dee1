"""Lockstep throughput through the actors, variants launched alternately (s16-fps).

The script now lives in ``docs/results/s17_fps/ab_launch.py`` (s17-fps added the tracking actor's service
time to its report); this runs it, so the s16 note's commands still work:

    python docs/results/s16_fps/ab_launch.py --variant /tmp/fps/base --variant $PWD --reps 4 --out X.json
"""
import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).resolve().parents[1] / "s17_fps" / "ab_launch.py"), run_name="__main__")
