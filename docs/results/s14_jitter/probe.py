"""Runs docs/results/s13_euroc/jitter.py (same arguments, CELL / SEED env) with optional patches of local mapping,
to pin down which part of a 3-frame keyframe cadence steadies a still EuRoC camera (docs/notes/s14-jitter.md):
  NOBA=1     local BA does nothing (keyframes inserted, landmarks created, culled; no landmark or pose refined)
  NOCORR=1   tracking ignores local BA's keyframe pose corrections
  NOPOS=1    tracking keeps each landmark's first position (BA's refinements never reach it)
  CULL=1     ORB-SLAM's keyframe culling after each insertion (a probe of bounding local mapping's cost)
  MAPTIME=1  prints local mapping's mean stage times per keyframe (insert / window / ba / cull / update), CPU of this process
Throw-away measurement script, run from the worktree root."""
import os, runpy, sys
sys.path.insert(0, os.getcwd())
import canopy.backend.local_ba as lb
import canopy.backend.local_mapper as lm
if os.environ.get("NOBA"):
    lb.LocalBundleAdjustmentMixin._bundle_adjust = lambda self, *a, **k: None
import canopy.frontend.tracker_map_view as tmv
_amu = tmv.TrackerMapViewMixin.apply_map_update
first_pos = {}


def amu(self, update):
    # NOCORR=1: the tracker ignores local BA's keyframe pose corrections; NOPOS=1: it keeps every
    # landmark at its creation position (BA's refined positions never reach tracking)
    if os.environ.get("NOCORR"):
        update.keyframe_poses = {}
    if os.environ.get("NOPOS"):
        import numpy as np
        pos = np.array(update.positions, float).reshape(-1, 3)
        for j, i in enumerate(np.asarray(update.landmark_ids).tolist()):
            if i in first_pos:
                pos[j] = first_pos[i]
            else:
                first_pos[i] = pos[j].copy()
        update.positions = pos
    return _amu(self, update)


tmv.TrackerMapViewMixin.apply_map_update = amu
if os.environ.get("FIXK"):  # FIXK=k: local BA keeps only the k most recent fixed keyframes
    _lw = lm.LocalMapper._local_window

    def lw(self, rec):
        local, fixed = _lw(self, rec)
        first = self._segment_first[rec.segment]
        keep = sorted(k for k in fixed if k != first)[-int(os.environ["FIXK"]):]
        return local, sorted(set(keep) | ({first} & set(fixed)))
    lm.LocalMapper._local_window = lw
if os.environ.get("CULL"):  # CULL=1: ORB-SLAM's KeyFrameCulling after each insertion (90 % of a keyframe's
    # landmarks seen by >= 3 other keyframes: the keyframe goes; scale test left out; never the segment's first
    # or the new keyframe)
    _ins0 = lm.LocalMapper.insert_keyframe

    def ins_cull(self, kf):
        up = _ins0(self, kf)
        rec = self.keyframes[kf.index]
        first = self._segment_first[rec.segment]
        keep = int(os.environ.get("CULL_KEEP", "1"))  # the newest CULL_KEEP keyframes are never culled
        for k in sorted(self.keyframes)[:-keep]:
            kr = self.keyframes[k]
            if k == first or kr.segment != rec.segment:
                continue
            lids = kr.landmark[kr.landmark >= 0].tolist()
            if lids and sum(len(self.landmarks[i].obs) - 1 >= 3 for i in lids) >= 0.9 * len(lids):
                for i in lids:
                    self._remove_observation(i, k)
                del self.keyframes[k]
                self.n_kf_culled = getattr(self, "n_kf_culled", 0) + 1
        return up
    lm.LocalMapper.insert_keyframe = ins_cull
stages = []
if os.environ.get("MAPTIME"):
    _ins = lm.LocalMapper.insert_keyframe

    def ins(self, kf):
        import time
        c0 = time.thread_time()
        up = _ins(self, kf)
        stages.append(dict(self.timings[-1], cpu=(time.thread_time() - c0) * 1e3, n_local=len(self.last_window[0]),
                           n_fixed=len(self.last_window[1])))
        return up
    lm.LocalMapper.insert_keyframe = ins
sys.argv = ["jitter.py"] + sys.argv[1:]
runpy.run_path("docs/results/s13_euroc/jitter.py", run_name="__main__")
if stages:
    keys = stages[0].keys()
    print("MAPCPU local mapping CPU %.1f ms per keyframe, %.2f ms per frame (95 frames)" % (
        sum(s["cpu"] for s in stages) / len(stages), sum(s["cpu"] for s in stages) / 95))
    third = max(len(stages) // 3, 1)
    print("MAPCPU per keyframe by thirds of the run: %s ms" % [round(sum(s["cpu"] for s in stages[i:i + third]) / len(stages[i:i + third]), 1)
                                                            for i in range(0, len(stages), third)])
    print("MAPTIME keyframes %d, mean ms per keyframe: %s" % (len(stages), {k: round(sum(s.get(k, 0) for s in stages) / len(stages), 1) for k in keys}))
