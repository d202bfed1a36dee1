import sys, warnings; warnings.simplefilter("ignore")
import os; sys.path.insert(0, os.getcwd()+'/benchmarks'); sys.path.insert(0, os.getcwd())
import numpy as np
import canopy.frontend.map_tracking as mt
import canopy.frontend.tracker as trk
from diagnose_tracking import run
from canopy.metrics import ape
calls = []; frames = []
orig = mt.refine_pose
def rp(T, X, meas, hr, sigma, calib, *a, **k):
    if os.environ.get('NOUR'): hr = np.zeros(len(X))
    est = orig(T, X, meas, hr, sigma, calib, *a, **k)
    calls.append(dict(n=len(X), hr=np.asarray(hr,bool).copy(), inl=est.inliers.copy(), sigma=np.asarray(sigma).copy(),
                      X=np.asarray(X).copy(), meas=np.asarray(meas,float).copy(), T=est.T_cam_world.copy(), T0=T.copy(), info=est.information.copy()))
    return est
mt.refine_pose = rp
origtrack = trk.Tracker.track
def track(self, frame, *a, **k):
    calls.clear()
    res = origtrack(self, frame, *a, **k)
    c = calls[-1] if calls else None
    frames.append((res.T_world_cam.copy(), None if c is None else dict(c), res.is_keyframe))
    return res
trk.Tracker.track = track
sets = [s for s in sys.argv[1:]]
src, res = run("euroc", os.environ.get("EPATH"), None, sets)
gt = src.ground_truth.poses[:res.n_frames]
est = res.trajectory.poses
online = np.array([f[0] for f in frames])
print("ATE final-traj %.3f mm  online %.3f mm  kfs %s" % (ape(est, gt, align="se3")['rmse']*1e3, ape(online, gt, align="se3")['rmse']*1e3, res.keyframe_indices))
rows = []
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: continue
    Tcw = np.linalg.inv(Twc)
    Pc = (c['X'] @ Tcw[:3,:3].T + Tcw[:3,3])
    inl = c['inl']; z = Pc[inl,2]; hr = c['hr'][inl]
    cov = np.linalg.inv(c['info']); sd = np.sqrt(np.diag(cov))
    rows.append((c['n'], inl.sum(), hr.sum(), np.median(z), (z<60*0.11).mean(), sd[3:].tolist() if False else sd.tolist()))
rows = rows
n = np.array([r[0] for r in rows]); ni=np.array([r[1] for r in rows]); ns=np.array([r[2] for r in rows])
sd = np.array([r[5] for r in rows])
print("matches med %d inliers med %d stereo-inliers med %d depth med %.2f m" % (np.median(n), np.median(ni), np.median(ns), np.median([r[3] for r in rows])))
print("predicted sd med (first 3 / last 3 of info order):", np.round(np.median(sd,axis=0)*1e3,3))
# observed frame-to-frame scatter of the online camera centre, compared to GT
c_est = online[:,:3,3]; c_gt = gt[:,:3,3]
d = np.diff(c_est,axis=0)-np.diff(c_gt,axis=0) if False else None
print("frame-to-frame |dc_est| med %.3f mm, |dc_gt| med %.3f mm" % (np.median(np.linalg.norm(np.diff(c_est,axis=0),axis=1))*1e3, np.median(np.linalg.norm(np.diff(c_gt,axis=0),axis=1))*1e3))
from canopy.metrics import align_trajectory
from canopy.frontend.geometry import project_stereo
al = align_trajectory(online, gt, with_scale=False)
e = al[:,:3,3]-gt[:,:3,3]
# in camera axes (x right, y down, z forward) of the gt camera
ec = np.einsum('nji,nj->ni', gt[:,:3,:3], e)
print("aligned err rms per cam axis (x,y,z) mm:", np.round(np.sqrt((ec**2).mean(0))*1e3,3))
# residuals at final pose
rl=[]; rr=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: continue
    pred,_=project_stereo(c['T'],c['X'],src.calibration); r=(c['meas']-pred)[c['inl']]/c['sigma'][c['inl'],None]
    rl.append(r[:,:2]); rr.append(r[c['hr'][c['inl']],2])
rl=np.concatenate(rl); rr=np.concatenate(rr)
C=[];O=[];Z=[];H=[];F=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: continue
    pred,Pc=project_stereo(c['T'],c['X'],src.calibration); r=(c['meas']-pred); r[:,2]*=c['hr']
    ch=(r**2).sum(1)/c['sigma']**2; m=c['inl']
    C.append(ch[m]); O.append(np.round(np.log(c['sigma'][m])/np.log(1.2)).astype(int)); Z.append(Pc[m,2]); H.append(c['hr'][m])
C=np.concatenate(C);O=np.concatenate(O);Z=np.concatenate(Z);H=np.concatenate(H)
print("inlier chi2 quantiles 50/90/95/99:", np.round(np.quantile(C,[.5,.9,.95,.99]),2), "share of chi2 sum from chi2>2: %.2f, >4: %.2f" % (C[C>2].sum()/C.sum(), C[C>4].sum()/C.sum()))
print("fraction inliers chi2>2: %.3f >4: %.3f" % ((C>2).mean(), (C>4).mean()))
for o in range(8): 
    mm=O==o
    if mm.any(): print(" octave",o,"n/frame %.0f"%(mm.sum()/len(frames)),"med chi2 %.2f"%np.median(C[mm]), "stereo %.2f"%H[mm].mean())
print("depth quantiles", np.round(np.quantile(Z,[.1,.5,.9]),2))
print("whitened residual rms u,v: %.3f %.3f  u_r: %.3f ; u_r - u_l rms %.3f" % (np.sqrt((rl[:,0]**2).mean()), np.sqrt((rl[:,1]**2).mean()), np.sqrt((rr**2).mean()), 0))
kfs = list(res.keyframe_indices)+[len(online)]
seg = np.zeros(len(online),int)
for k,(a,b) in enumerate(zip(kfs[:-1],kfs[1:])): seg[a:b]=k
segmean = np.array([e[seg==s].mean(0) for s in seg])
print("err rms total %.3f, between-segment (KF) part %.3f, within-segment part %.3f mm" % (np.sqrt((e**2).sum(1).mean())*1e3, np.sqrt((segmean**2).sum(1).mean())*1e3, np.sqrt(((e-segmean)**2).sum(1).mean())*1e3))
hp = e[1:]-e[:-1]
print("frame-diff of err rms %.3f mm (white noise of sd s per frame gives sqrt2*s)" % (np.sqrt((hp**2).sum(1).mean())*1e3))
np.save('/tmp/j/canopy_err.npy', e)

k=9; sm = np.array([e[max(0,i-k//2):i+k//2+1].mean(0) for i in range(len(e))])
print("SUMMARY", sys.argv[1:], os.environ.get('NOUR'), "ATE %.3f online %.3f frame-diff rms %.3f smooth %.3f resid %.3f axes %s" % (ape(est, gt, align="se3")['rmse']*1e3, ape(online, gt, align="se3")['rmse']*1e3, np.sqrt((hp**2).sum(1).mean())*1e3, np.sqrt((sm**2).sum(1).mean())*1e3, np.sqrt(((e-sm)**2).sum(1).mean())*1e3, np.round(np.sqrt((ec**2).mean(0))*1e3,3)))
same=[]; duv=[]; dur=[]; churn=[]; lvchg=[]
prev=None
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: prev=None; continue
    m=c['inl']; keys={tuple(np.round(x,9)):(c['meas'][j], c['hr'][j], c['sigma'][j]) for j,x in zip(np.flatnonzero(m), c['X'][m])}
    if prev is not None:
        common=set(keys)&set(prev)
        churn.append(1-len(common)/max(len(keys),1))
        for kk in common:
            a,ha,sa=keys[kk]; b,hb,sb=prev[kk]
            duv.append(np.abs(a[:2]-b[:2]).max()); lvchg.append(sa!=sb)
            if ha and hb: dur.append(a[2]-b[2])
    prev=keys
duv=np.array(duv); dur=np.array(dur)
print("CHURN inliers not in previous frame's inlier set: %.3f; common: u,v identical %.3f, changed>0.5px %.3f, level changed %.3f; u_r change rms %.3f px, |du_r|<0.01 %.3f" % (np.mean(churn), (duv==0).mean(), (duv>0.5).mean(), np.mean(lvchg), np.sqrt((dur**2).mean()), (np.abs(dur)<0.01).mean()))
from canopy.frontend.geometry import stereo_pose_jacobian
prev=None; comp={'uv':[], 'ur':[], 'total':[]}
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: prev=None; continue
    m=c['inl']; idx=np.flatnonzero(m)
    keys={tuple(np.round(c['X'][j],9)):j for j in idx}
    if prev is not None and not kf and not frames[i-1][2]:
        pc, pkeys = prev
        Pc = c['X'] @ c['T'][:3,:3].T + c['T'][:3,3]
        J = stereo_pose_jacobian(Pc, src.calibration)  # (N,3,6)
        w = np.repeat((1/c['sigma']**2)[:,None],3,1); w[:,2]*=c['hr']; w[~m]=0
        H = np.einsum('nki,nk,nkj->ij', J, w, J)
        Hi = np.linalg.inv(H)
        dr_uv = np.zeros((len(c['X']),3)); dr_ur = np.zeros((len(c['X']),3))
        for kk,j in keys.items():
            if kk in pkeys:
                jp = pkeys[kk]
                d = c['meas'][j]-pc['meas'][jp]
                dr_uv[j,:2] = d[:2]
                if c['hr'][j] and pc['hr'][jp]: dr_ur[j,2] = d[2]-d[0]  # disparity change beyond u_l's
        for name, dr in (('uv', dr_uv), ('ur', dr_ur)):
            # a change in u_l moves u_r with it (same disparity): give the uv component both
            if name=='uv': dr = dr.copy(); dr[:,2] = dr[:,0]*c['hr']
            dxi = Hi @ np.einsum('nki,nk,nk->i', J, w, dr)
            comp[name].append(np.linalg.norm(c['T'][:3,:3].T @ dxi[3:]))
        comp['total'].append(np.linalg.norm(Twc[:3,3]-frames[i-1][0][:3,3]))
    prev=(c, keys)
print("DECOMP frame-to-frame camera-centre change rms mm: total %.3f; from u,v changes of common points %.3f; from disparity changes %.3f" % tuple(np.sqrt(np.mean(np.square(comp[k])))*1e3 for k in ('total','uv','ur')))
mv=[]; prev=None
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: prev=None; continue
    m=c['inl']; keys={tuple(np.round(c['X'][j],9)):j for j in np.flatnonzero(m)}
    if prev is not None:
        pc,pk=prev
        for kk,j in keys.items():
            if kk in pk:
                jp=pk[kk]; d=np.abs(c['meas'][j,:2]-pc['meas'][jp,:2]).max()
                if d>0: mv.append((d/c['sigma'][j], c['sigma'][j]==pc['sigma'][jp]))
    prev=(c,keys)
mv=np.array(mv)
same=mv[:,1]>0
q=mv[same,0]
print("MOVES (same level) in level px: n=%d  <=1.01: %.2f  <=2.01: %.2f  >2: %.2f ; level changed moves: %d" % (len(q), (q<=1.01).mean(), ((q>1.01)&(q<=2.01)).mean(), (q>2.01).mean(), (~same).sum()))
prev=None; dv=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: prev=None; continue
    m=c['inl']; keys={tuple(np.round(c['X'][j],9)):j for j in np.flatnonzero(m)}
    if prev is not None:
        pc,pk=prev
        dv += [c['meas'][j,:2]-pc['meas'][pk[k],:2] for k,j in keys.items() if k in pk]
    prev=(c,keys)
dv=np.array(dv)
print("OURS common inliers: keypoint change rms %.3f px (x %.3f y %.3f), n/frame %.0f" % (np.sqrt((dv**2).sum(1).mean()), np.sqrt((dv[:,0]**2).mean()), np.sqrt((dv[:,1]**2).mean()), len(dv)/len(frames)))
import cv2
K=src.calibration.K; cs=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: continue
    m=c['inl']; rv,_=cv2.Rodrigues(c['T'][:3,:3])
    ok, rv, tv = cv2.solvePnP(c['X'][m], c['meas'][m,:2], K, None, rv.copy(), c['T'][:3,3].copy(), useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    R,_=cv2.Rodrigues(rv); cs.append(-R.T@tv.ravel())
cs=np.array(cs)
print("OURS unweighted mono LS on final inliers: frame-diff rms %.3f mm" % (np.sqrt((np.diff(cs,axis=0)**2).sum(1).mean())*1e3))
prev=None; st=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: prev=None; continue
    m=c['inl']; keys={tuple(np.round(c['X'][j],9)):j for j in np.flatnonzero(m)}
    if prev is not None:
        pc,pk=prev
        v=np.array([c['meas'][j,:2]-pc['meas'][pk[k],:2] for k,j in keys.items() if k in pk])
        if len(v) > 10: st.append((v.mean(0)*np.sqrt(len(v)), np.sqrt((v**2).mean(0))))
    prev=(c,keys)
st=np.array(st)
print("OURS per-frame mean change x sqrt(N) rms (x,y): %s vs per-point rms %s" % (np.round(np.sqrt((st[:,0]**2).mean(0)),3), np.round(np.sqrt((st[:,1]**2).mean(0)),3)))
exec(open(os.path.join(os.path.dirname(os.path.abspath(__file__)), 'geom.py')).read())
G=[]; depth=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: continue
    m=c['inl']; Pc=c['X'][m]@c['T'][:3,:3].T+c['T'][:3,3]
    G.append(geom(Pc, src.calibration.K[0,0])); depth.append(np.median(Pc[:,2]))
print("OURS geometry: translation sd per 1 px of independent noise (unweighted mono) med %.3f mm; depth med %.2f m" % (np.median(G)*1e3, np.median(depth)))
Z=[];UV=[]
for i,(Twc,c,kf) in enumerate(frames):
    if c is None: continue
    m=c['inl']; Pc=c['X'][m]@c['T'][:3,:3].T+c['T'][:3,3]; Z.append(Pc[:,2]); UV.append(c['meas'][m,:2])
Z=np.concatenate(Z); UV=np.concatenate(UV)
print("OURS tracked depth quantiles 5/25/50/75/95: %s; u range 5-95%%: %s v: %s" % (np.round(np.quantile(Z,[.05,.25,.5,.75,.95]),2), np.round(np.quantile(UV[:,0],[.05,.95])), np.round(np.quantile(UV[:,1],[.05,.95]))))
