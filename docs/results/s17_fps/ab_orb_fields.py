"""OrbExtractor.extract of this checkout against another checkout's (--base), image by image, on the
EuRoC snippet's left and right images (EuRoC's tracking config: cv2.ORB): outputs identical, and
the thread CPU per image of each, alternating (s17-fps: octaves / responses by attrgetter).

    PYTHONPATH=$PWD python docs/results/s17_fps/ab_orb_fields.py --base /tmp/base --reps 5
"""
import argparse
import importlib.util
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from canopy.config import load_run_config  # noqa: E402
from canopy.frontend.features import OrbExtractor  # noqa: E402
from canopy.sources import open_source  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--base", type=Path, required=True)
ap.add_argument("--reps", type=int, default=5)
a = ap.parse_args()
spec = importlib.util.spec_from_file_location("base_features", a.base / "canopy/frontend/features.py")
base = importlib.util.module_from_spec(spec)
sys.modules["base_features"] = base  # dataclasses look their module up
spec.loader.exec_module(base)
warnings.simplefilter("ignore")
tp = load_run_config("euroc").tracking
src = open_source("euroc", None)
images = [im for i in range(len(src)) for im in (src.frame(i).left, src.frame(i).right)]
new, old = OrbExtractor(tp), base.OrbExtractor(tp)
same = 0
for im in images:
    x, y = new.extract(im), old.extract(im)
    same += all(np.array_equal(getattr(x, f), getattr(y, f)) and getattr(x, f).dtype == getattr(y, f).dtype
                for f in ("uv", "octave", "response", "descriptors"))
print(f"{len(images)} EuRoC images, outputs identical {same}/{len(images)}")
times = {"base": [], "this": []}
for rep in range(a.reps):
    for name, ex in (("base", old), ("this", new))[:: 1 if rep % 2 == 0 else -1]:
        t0 = time.thread_time()
        for im in images:
            ex.extract(im)
        times[name].append((time.thread_time() - t0) / len(images) * 1e3)
b, t = np.median(times["base"]), np.median(times["this"])
print(f"thread CPU per image, median of {a.reps}: base {b:.3f} ms, this {t:.3f} ms, difference {t - b:+.3f} ms")
