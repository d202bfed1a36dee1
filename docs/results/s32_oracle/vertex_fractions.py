"""s32: histogram of the sub-pixel parts of the clean KITTI run's stereo matches at their pyramid level (pixel
locking shows as a pile-up at 0). Argument "equi": with equiangular_vertex.py imported.

    PYTHONPATH=$PWD python docs/results/s32_oracle/vertex_fractions.py [equi]
"""
import sys, numpy as np
sys.path.insert(0, __import__('os').path.dirname(__file__))
if len(sys.argv)>1 and sys.argv[1]=='equi': import equiangular_vertex  # noqa: F401
import canopy.frontend.stereo as st
fr=[]
orig=st.refine_and_accept
def w(ref_left, ref_right, left, li, ur0, sf, *a, **k):
    out=orig(ref_left, ref_right, left, li, ur0, sf, *a, **k)
    li2, ur, disp = out
    off = a[1].disparity_offset_for(left.extractor)
    # right column at the level before offset
    x = (ur + off) / sf[left.octave[li2]]
    xl = np.round(left.uv[li2,0]/sf[left.octave[li2]])
    fr.append(((xl - x) % 1.0))
    return out
st.refine_and_accept=w
from benchmarks.bench_enhance_diagnose import run
from canopy.sources import BUNDLED_DATA
run(BUNDLED_DATA['kitti'],BUNDLED_DATA['kitti'],'kitti',{'method':'auto'},{},None,stereo=False,kind='kitti')
f=np.concatenate(fr)
h,_=np.histogram(f,bins=10,range=(0,1))
print(len(f), ' '.join('%.3f'%x for x in h/len(f)))
