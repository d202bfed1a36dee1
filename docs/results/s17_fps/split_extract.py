"""Thread-CPU split of the tracker's extractor on the KITTI snippet's left images, in process (s17-fps):
each part of CellExtractor.extract wrapped with a thread_time() clock, 3 passes over the 51 images.

    PYTHONPATH=$PWD python docs/results/s17_fps/split_extract.py kitti
"""
import sys, time
import numpy as np, cv2
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config
from canopy.sources import open_source
from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend import cell_extractor as ce
from canopy.frontend import cell_levels as cl
ds = sys.argv[1] if len(sys.argv) > 1 else 'kitti'
cfg = load_run_config(ds); tp = cfg.tracking
src = open_source(ds, None)
imgs = [src.frame(i).left for i in range(len(src))]
ex = tracking_extractor(tp, responses=False)
acc = {}
def wrap(obj, name, key):
    f = getattr(obj, name)
    def g(*a, **k):
        t = time.thread_time(); r = f(*a, **k); acc[key] = acc.get(key, 0) + time.thread_time() - t; return r
    setattr(obj, name, g)
C = ce.CellExtractor
wrap(C, 'pyramid', 'pyramid'); wrap(ce, '_fast_points', 'fast_whole'); wrap(C, '_fallback_corners', 'fallback')
wrap(ce, 'quadtree_select', 'quadtree'); wrap(C, '_describe', 'describe'); wrap(ce, 'ic_angles_levels', 'ic_angles')
wrap(ce, 'image_noise_sigma', 'noise_sigma')
for rep in range(3):
    for im in imgs:
        t = time.thread_time(); ex.extract(im); acc['total'] = acc.get('total', 0) + time.thread_time() - t
n = 3 * len(imgs)
for k, v in sorted(acc.items(), key=lambda kv: -kv[1]):
    print(f"{k:12s} {v / n * 1e3:7.3f} ms/image")
