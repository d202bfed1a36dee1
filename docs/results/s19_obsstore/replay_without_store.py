"""benchmarks/ab_mapping.py --replay with LandmarkStore.observations off (the ObservationTable fallback of sparse ids):
    PYTHONPATH=$PWD python docs/results/s19_obsstore/replay_without_store.py benchmarks/ab_mapping.py --replay REC --reps 1
"""
import runpy, sys
import canopy.backend.map_store as m
orig = m.LandmarkStore.__init__
def init(self):
    orig(self)
    self.observations = None
m.LandmarkStore.__init__ = init
sys.argv = [sys.argv[1]] + sys.argv[2:]
import os; sys.path.insert(0, os.path.dirname(os.path.abspath(sys.argv[0])))
runpy.run_path(sys.argv[0], run_name="__main__")
