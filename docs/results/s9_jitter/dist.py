import sys, os, warnings; warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
from canopy.sources import open_source
from canopy.config import load_run_config
from canopy.frontend.features import OrbExtractor
from canopy.frontend.cell_extractor import CellExtractor
from canopy.frontend.stereo import match_stereo
src = open_source("euroc", None); f = src.frame(10)
tp = load_run_config("euroc").tracking
for name, ex in (("opencv", OrbExtractor(tp)),):
    L = ex.extract(f.left); R = ex.extract(f.right)
    st = match_stereo(L, R, f.left, f.right, src.calibration, tp)
    q = lambda a: np.round(np.quantile(a,[.05,.5,.95]))
    print(name, "kps", len(L), "u", q(L.uv[:,0]), "v", q(L.uv[:,1]), "| stereo", st.valid.sum(), "u", q(L.uv[st.valid,0]), "v", q(L.uv[st.valid,1]), "depth", np.round(np.quantile(st.depth[st.valid],[.05,.5,.95]),2))
    H,_,_ = np.histogram2d(L.uv[:,0], L.uv[:,1], bins=[4,3], range=[[0,752],[0,480]]); print(" kps per 4x3 block (cols=v):\n", H.astype(int))
    H,_,_ = np.histogram2d(L.uv[st.valid,0], L.uv[st.valid,1], bins=[4,3], range=[[0,752],[0,480]]); print(" stereo per block:\n", H.astype(int))
