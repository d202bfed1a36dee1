"""Per-frame enhancement noise sigma (the fill-in gate's figure) of preset cells: enhancement only."""
import sys, json
from dataclasses import replace
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path.cwd()))
from benchmarks.bench_enhance_diagnose import enhance_pair
from canopy.config import load_run_config
from canopy.enhance import make_enhancer
from canopy.sources import open_source
enh = make_enhancer(replace(load_run_config("synthetic").enhancement, method="auto"))
for path in sys.argv[1:]:
    src = open_source("euroc", path)
    s = []
    for i in range(len(src)):
        fr = src.frame(i)
        _, info = enh(fr.left)
        s.append(info["noise_sigma"] or 0.0)
    s = np.array(s)
    print(Path(path).name, f"n {len(s)} min {s.min():.2f} p5 {np.percentile(s,5):.2f} med {np.median(s):.2f} p95 {np.percentile(s,95):.2f} max {s.max():.2f}", flush=True)
