"""Paths the s23-kittidehaze scratch scripts share (run them as ``python docs/results/s23_kittidehaze/X.py``)."""
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]                       # the repository
sys.path[:0] = [str(HERE), str(ROOT / "benchmarks"), str(ROOT)]
CELLS = os.environ.get("CELLS_CACHE", "/tmp/kittidehaze-cache")   # the grid runner's --cells-cache
CLEAN = str(ROOT / "data/kitti06_snippet")
ORACLE_T = os.environ.get("ORACLE_T", "/tmp/kittidehaze/oracle_t.npz")   # written by oracle_t.py
