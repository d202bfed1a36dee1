"""Exact alternatives to cell_levels.ic_angles_levels on recorded KITTI calls (s17-fps): each checked
bit for bit against the shipped function, then timed alternately (thread / process CPU per image).
None is faster without OpenBLAS threads (matmul_f32 uses them: its thread CPU hides their work).

    PYTHONPATH=$PWD python docs/results/s17_fps/ab_ic_angles.py
"""
import sys, time
import numpy as np, cv2
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
from canopy.config import load_run_config
from canopy.sources import open_source
from canopy.frontend.noisy_features import tracking_extractor
from canopy.frontend import cell_extractor as ce, cell_levels as cl
cfg = load_run_config('kitti'); tp = cfg.tracking
src = open_source('kitti', None)
imgs = [src.frame(i).left for i in range(0, len(src), 3)]
ex = tracking_extractor(tp, responses=False)
calls = []
orig = ce.ic_angles_levels
def rec(levels, x, y, starts):
    calls.append((levels, x.copy(), y.copy(), np.array(starts)))
    return orig(levels, x, y, starts)
ce.ic_angles_levels = rec
for im in imgs: ex.extract(im)
print(len(calls), [int(c[3][-1]) for c in calls[:5]])
H = cl.HALF_PATCH; W = 2*H+1
M2 = cl.MASK_UV.reshape(2, -1).T.copy()  # (961,2) float32
Mi = cl.MASK_UV.reshape(2, -1).astype(np.int32)
def win_of(img):
    h, wd = img.shape; s0, s1 = img.strides
    return np.ndarray((h-W+1, wd-W+1, W, W), np.uint8, img, 0, (s0, s1, s0, s1))
def v_matmul(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H].reshape(b-a, -1).astype(np.float32)
            np.matmul(p, M2, out=m[a:b])
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
def v_cvgemm(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H].reshape(b-a, -1)
            pf = p.astype(np.float32)
            m[a:b] = cv2.gemm(pf, M2, 1.0, None, 0.0)
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
# rows approach: row sums within circle via cumsum along row of patch rows
umax = np.zeros(2*H+1, np.int64)
for v in range(-H, H+1):
    umax[v+H] = cl.CIRCLE_U[cl.CIRCLE_V == v].max()
def v_rows(levels, x, y, starts):
    # gather (K,31,31) uint8; m01 = sum_v v*rowsum_circ ; m10 = sum u*I
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H]
            p16 = p.reshape(b-a, -1)
            m[a:b, 0] = (p16 @ Mi[0])  # int matmul
            m[a:b, 1] = (p16 @ Mi[1])
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
def v_filter(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    return None
variants = [('einsum', orig), ('matmul_f32', v_matmul), ('cvgemm', v_cvgemm), ('int_matmul', v_rows)]
for name, f in variants:
    ok = all(np.array_equal(f(*c), orig(*c)) for c in calls)
    print(name, 'identical' if ok else 'DIFFERENT')
T = {n: [] for n, _ in variants}
for rep in range(5):
    for name, f in variants:
        t = time.thread_time()
        for c in calls: f(*c)
        T[name].append((time.thread_time() - t) / len(calls) * 1e3)
for n, v in T.items(): print(f"{n:12s} {np.median(v):.3f} ms/image  {np.round(v,3)}")
print('---- split')
circ = (cl.MASK_UV[0] != 0) | (cl.MASK_UV[1] != 0)
circ[H, :] = False; circ[H, H-umax[H]:H+umax[H]+1] = True  # row 0: u mask zero at u=0 col; fix by umax
circ = np.zeros((W, W), bool)
for v in range(-H, H+1): circ[v+H, H-umax[v+H]:H+umax[v+H]+1] = True
circ8 = circ.astype(np.uint8) * 255
uu = np.arange(-H, H+1, dtype=np.int64)
def gather_only(levels, x, y, starts):
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a: p = win_of(img)[y[a:b]-H, x[a:b]-H]
def v_sums(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H]
            np.bitwise_and(p, circ8, out=p)
            rows = p.sum(axis=2, dtype=np.int32)   # (K,31)
            cols = p.sum(axis=1, dtype=np.int32)   # (K,31)
            m[a:b, 0] = cols @ uu
            m[a:b, 1] = rows @ uu
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
def v_f32einsum(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H].astype(np.float32)
            np.einsum("kij,mij->km", p, cl.MASK_UV, out=m[a:b])
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
def v_sums2(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H]
            np.bitwise_and(p, circ8, out=p)
            k = b - a
            rows = np.add.reduce(p.reshape(k*W, W), axis=1, dtype=np.uint16).reshape(k, W)  # <= 31*255 fits u16
            cols = np.add.reduce(p, axis=1, dtype=np.uint16)
            m[a:b, 0] = cols.astype(np.int32) @ uu.astype(np.int32)
            m[a:b, 1] = rows.astype(np.int32) @ uu.astype(np.int32)
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
def v_cvreduce(levels, x, y, starts):
    n = int(starts[-1]); m = np.empty((n, 2), np.float32)
    for l, img in enumerate(levels):
        a, b = int(starts[l]), int(starts[l+1])
        if b > a:
            p = win_of(img)[y[a:b]-H, x[a:b]-H]
            np.bitwise_and(p, circ8, out=p)
            k = b - a
            rows = cv2.reduce(p.reshape(k*W, W), 1, cv2.REDUCE_SUM, dtype=cv2.CV_32S).reshape(k, W)
            cols = np.add.reduce(p, axis=1, dtype=np.uint16)
            m[a:b, 0] = cols.astype(np.float32) @ uu.astype(np.float32)
            m[a:b, 1] = rows.astype(np.float32) @ uu.astype(np.float32)
    return np.mod(np.degrees(np.arctan2(m[:, 1], m[:, 0])), 360.0).astype(np.float32)
variants = [('einsum', orig), ('gather_only', gather_only), ('sums', v_sums), ('f32einsum', v_f32einsum), ('sums_u16', v_sums2), ('cvreduce', v_cvreduce)]
for name, f in variants[2:]:
    ok = all(np.array_equal(f(*c), orig(*c)) for c in calls)
    print(name, 'identical' if ok else 'DIFFERENT')
T = {n: [] for n, _ in variants}
for rep in range(7):
    for name, f in variants:
        t = time.process_time()
        for c in calls: f(*c)
        T[name].append((time.process_time() - t) / len(calls) * 1e3)
for n, v in T.items(): print(f"{n:12s} {np.median(v):.3f} ms/image  {np.round(v,3)}")
