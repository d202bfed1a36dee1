import sys, glob, cv2, numpy as np
from dataclasses import replace
from canopy.config import load_run_config
from canopy.enhance.auto import auto_treat
from canopy.enhance.fast import tracking_fast_arguments
from canopy.frontend.enhanced_extractor import EnhancedCellsRule
cfg = load_run_config("synthetic")
ep, tp = cfg.enhancement, cfg.tracking
tp = replace(tp, enhanced_cells_min_corners=10, enhanced_cells_corner_weight=0.2)
for d in sys.argv[1:]:
    files = sorted(glob.glob(d + "/mav0/cam0/data/*.png"))[::10]
    rule = EnhancedCellsRule(tp); n_cells = 0; counts = []
    for f in files:
        img = cv2.imread(f, 0)
        out, dec, sig, g = auto_treat(img, ep)
        fa = tracking_fast_arguments(out, dec, ep, tp.n_features)
        if dec == "none": continue
        r = rule.fallback(out, fa.get("fast_threshold"), fa.get("fast_fallback", 7))
        counts.append(rule.last_corners); n_cells += r is not None
    print(d.split("/")[-1], "frames", len(counts), "to cells", n_cells, "corners med", np.median(counts) if counts else None, "min/max", min(counts, default=None), max(counts, default=None), fa)
