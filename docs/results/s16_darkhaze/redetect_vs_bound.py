"""s16-darkhaze §1a: does the Cramér-Rao / Förstner location bound of a keypoint (sigma_n^2 M^-1, M its
structure tensor with the noise part removed) predict how far it lands from the same corner on the clean
frame? cv2.ORB on every 5th frame of a KITTI cell and of the clean snippet. Usage:
    PYTHONPATH=$PWD python docs/results/s16_darkhaze/redetect_vs_bound.py kitti-all-g1-b0.06-high-seed0"""
import sys, glob, numpy as np, cv2
sys.path.insert(0,'.')
from canopy.sources import BUNDLED_DATA
from canopy.enhance.noise import estimate_noise
from scipy.spatial import cKDTree


def location_sigma(image, uv, octave, scale_factors, noise_sigma, h=3, cap=8.0):
    """sqrt(sigma_n^2 trace(M_signal^-1) / 2) in level pixels x s^o (the removed pose-sigma option's bound)."""
    k, p = len(uv), 2 * h + 3
    off = np.arange(-(h + 1), h + 2, dtype=np.float32)
    s = scale_factors[octave].astype(np.float32)[:, None, None]
    mx = (uv[:, 0].astype(np.float32)[:, None, None] + s * off[None, None, :]).repeat(p, axis=1)
    my = (uv[:, 1].astype(np.float32)[:, None, None] + s * off[None, :, None]).repeat(p, axis=2)
    P = cv2.remap(image.astype(np.float32), mx.reshape(k * p, p), my.reshape(k * p, p), cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REFLECT_101).reshape(k, p, p)
    gx = 0.5 * (P[:, 1:-1, 2:] - P[:, 1:-1, :-2]); gy = 0.5 * (P[:, 2:, 1:-1] - P[:, :-2, 1:-1])
    sxx, sxy, syy = (np.einsum("kij,kij->k", a, b) for a, b in ((gx, gx), (gx, gy), (gy, gy)))
    noise = (2 * h + 1) ** 2 * noise_sigma ** 2 / 2
    ht, disc = 0.5 * (sxx + syy), np.sqrt(0.25 * (sxx - syy) ** 2 + sxy ** 2)
    l1, l2 = np.maximum(ht - disc - noise, 0), np.maximum(ht + disc - noise, 0)
    with np.errstate(divide="ignore"):
        var = 0.5 * noise_sigma ** 2 * (1 / l1 + 1 / l2)
    var = np.minimum(np.where(np.isfinite(var), var, cap ** 2), cap ** 2)
    return np.sqrt(var) * scale_factors[octave]

sf = 1.2**np.arange(8)
cl = sorted(glob.glob(str(BUNDLED_DATA["kitti"])+"/image_l/*.png"))
cell = sys.argv[1]
dg = sorted(glob.glob(f"/work/cache/degraded_darkhaze/{cell}/image_l/*.png"))
D=[];S=[];O=[]
for f in range(0, 51, 5):
    a = cv2.imread(cl[f],0); b = cv2.imread(dg[f],0)
    orb = cv2.ORB_create(2000,1.2,8)
    ka = orb.detect(a,None); kb = orb.detect(b,None)
    ua = np.array([k.pt for k in ka]); oa=np.array([k.octave for k in ka])
    ub = np.array([k.pt for k in kb],np.float32); ob=np.array([k.octave for k in kb])
    sn = estimate_noise(b, rows_fraction=0.5)
    s = location_sigma(b, ub, ob, sf, sn)
    for o in range(8):
        ma, mb = oa==o, ob==o
        if ma.sum()<5 or mb.sum()<5: continue
        t = cKDTree(ua[ma]/sf[o]); d, i = t.query(ub[mb]/sf[o])
        ok = d < 2.0
        D.append(d[ok]); S.append(s[mb][ok]/sf[o]); O.append(np.full(ok.sum(),o))
D=np.concatenate(D);S=np.concatenate(S);O=np.concatenate(O)
print(cell, "n", len(D), "noise", round(sn,2))
qs = np.percentile(S,[0,20,40,60,80,95,100])
for lo,hi in zip(qs[:-1],qs[1:]):
    m=(S>=lo)&(S<=hi)
    print(" sigma_CR %.3f-%.3f  n %5d  redetection rms (level px) %.3f  p50 %.3f" % (lo,hi,m.sum(), np.sqrt((D[m]**2).mean()), np.median(D[m])))
