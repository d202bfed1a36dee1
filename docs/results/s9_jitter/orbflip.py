import sys, os, pickle, warnings; warnings.simplefilter("ignore"); sys.path.insert(0, os.getcwd())
import numpy as np
from scipy.spatial import cKDTree
from canopy.sources import open_source
src = open_source("euroc", None); K = src.calibration.K
d = pickle.load(open("/tmp/j/orb2.pkl","rb"))
A = np.eye(3)
def proj(x):
    Tcw = np.linalg.inv(x['pose']); P = x['mp'] @ Tcw[:3,:3].T + Tcw[:3,3]
    return (P[:,:2]/P[:,2:3]) * [K[0,0],K[1,1]] + [K[0,2],K[1,2]]
# 2-D affine map projections -> keypoints by iterated nearest neighbours (ORB-SLAM3's own rectification has its own K)
U=np.concatenate([proj(x) for x in d[:20]]); KP=[cKDTree(x['kp']) for x in d[:20]]
for it in range(15):
    Ua = U @ A[:2,:2].T + A[:2,2]
    tgt=[]; src_=[]; o=0
    for x,t in zip(d[:20],KP):
        n=len(x['mp']); dist,j=t.query(Ua[o:o+n]); m=dist< (8 if it<5 else 2.5)
        tgt.append(x['kp'][j[m]]); src_.append(U[o:o+n][m]); o+=n
    S=np.concatenate(src_); T=np.concatenate(tgt)
    M,_,_,_=np.linalg.lstsq(np.c_[S,np.ones(len(S))], T, rcond=None); A[:2,:2]=M[:2].T; A[:2,2]=M[2]
print("affine", np.round(A,4), len(S))
def assoc(x):
    uv = proj(x) @ A[:2,:2].T + A[:2,2]
    dist, j = cKDTree(x['kp']).query(uv)
    return {tuple(np.round(p,5)): (x['kp'][jj], dd) for p,jj,dd in zip(x['mp'], j, dist)}
prev=None; mv=[]; dd=[]; churn=[]
for x in d:
    a = assoc(x); dd += [v[1] for v in a.values()]
    if prev is not None:
        com = set(a)&set(prev); churn.append(1-len(com)/len(a))
        mv += [np.abs(a[k][0]-prev[k][0]).max() for k in com]
    prev=a
mv=np.array(mv)
print("ORB-SLAM3 tracked points: projection-to-nearest-keypoint px median %.2f 90%% %.2f; churn %.3f; common: identical %.3f, moved>0.5px %.3f" % (np.median(dd), np.quantile(dd,.9), np.mean(churn), (mv<1e-3).mean(), (mv>0.5).mean()))
import cv2
K2 = np.array([[K[0,0]*A[0,0], 0, K[0,2]*A[0,0]+A[0,2]], [0, K[1,1]*A[1,1], K[1,2]*A[1,1]+A[1,2]], [0,0,1.0]])
cs=[]; cr=[]
for x in d:
    Tcw = np.linalg.inv(x['pose'])
    uv = proj(x) @ A[:2,:2].T + A[:2,2]
    dist, j = cKDTree(x['kp']).query(uv); m = dist < 1.5
    rv,_ = cv2.Rodrigues(Tcw[:3,:3])
    ok, rv, tv = cv2.solvePnP(x['mp'][m].astype(np.float64), x['kp'][j[m]].astype(np.float64), K2, None, rv.copy(), Tcw[:3,3].copy(), useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    R,_ = cv2.Rodrigues(rv); cs.append(-R.T @ tv.ravel()); cr.append(x['pose'][:3,3])
cs=np.array(cs); cr=np.array(cr)
f=lambda c: np.sqrt((np.diff(c,axis=0)**2).sum(1).mean())*1e3
print("ORB-SLAM3 frame-diff rms: reported %.3f mm; our unweighted mono LS on its tracked points/keypoints %.3f mm; mean |re-solve - reported| %.3f mm" % (f(cr), f(cs), np.linalg.norm(cs-cr,axis=1).mean()*1e3))
prev=None; dv=[]
for x in d:
    a = assoc(x)
    if prev is not None:
        for k in set(a)&set(prev):
            if a[k][1] < 1.5 and prev[k][1] < 1.5: dv.append(a[k][0]-prev[k][0])
    prev=a
dv=np.array(dv)
print("ORB-SLAM3 common tracked points: keypoint change rms %.3f px (x %.3f y %.3f), n/frame %.0f" % (np.sqrt((dv**2).sum(1).mean()), np.sqrt((dv[:,0]**2).mean()), np.sqrt((dv[:,1]**2).mean()), len(dv)/len(d)))
prev=None; st=[]
for x in d:
    a = assoc(x)
    if prev is not None:
        v=np.array([a[k][0]-prev[k][0] for k in set(a)&set(prev) if a[k][1]<1.5 and prev[k][1]<1.5]).reshape(-1,2)
        if len(v) > 10: st.append((v.mean(0)*np.sqrt(len(v)), np.sqrt((v**2).mean(0))))
    prev=a
st=np.array(st)
print("ORB-SLAM3 per-frame mean change x sqrt(N) rms (x,y): %s vs per-point rms %s" % (np.round(np.sqrt((st[:,0]**2).mean(0)),3), np.round(np.sqrt((st[:,1]**2).mean(0)),3)))
import sys; sys.path.insert(0, str(__import__('pathlib').Path(__file__).parent))
from geom import geom  # pose position spread per px of keypoint noise (geom.py)
G=[]; depth=[]
for x in d:
    Tcw=np.linalg.inv(x['pose']); P=x['mp']@Tcw[:3,:3].T+Tcw[:3,3]
    uv=proj(x)@A[:2,:2].T+A[:2,2]; dist,j=cKDTree(x['kp']).query(uv); m=dist<1.5
    G.append(geom(P[m], K2[0,0])); depth.append(np.median(P[m,2]))
print("ORB-SLAM3 geometry: translation sd per 1 px of independent noise (unweighted mono) med %.3f mm; depth med %.2f m" % (np.median(G)*1e3, np.median(depth)))
Z=[];UV=[]
for x in d:
    Tcw=np.linalg.inv(x['pose']); P=x['mp']@Tcw[:3,:3].T+Tcw[:3,3]; Z.append(P[:,2]); UV.append(proj(x)@A[:2,:2].T+A[:2,2])
Z=np.concatenate(Z); UV=np.concatenate(UV)
print("ORB-SLAM3 tracked depth quantiles 5/25/50/75/95: %s; u range 5-95%%: %s v: %s (its image 752x480 zoomed 4.7%%)" % (np.round(np.quantile(Z,[.05,.25,.5,.75,.95]),2), np.round(np.quantile(UV[:,0],[.05,.95])), np.round(np.quantile(UV[:,1],[.05,.95]))))
