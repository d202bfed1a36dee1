"""s17-kittihaze: the sampled-noise model of the disparity bound against diag_stereo.py's two-draw noise
measurement (KITTI g1-b0.06-high seed 0, /tmp/kh_ds_g1_s0.npz), and the old (white) against the new rule's
flagged sets."""
import numpy as np, json
z=np.load("/tmp/kh_ds_g1_s0.npz"); P=z["pts"]; n=int(z["n"]); h=5
i,u,v,oc,depth,de,dr,sxx,nxx,nvar,unc=P.T
fr=json.loads(str(z["frames"])); sig=np.array([fr[int(k)]["robust"] for k in i])
s=1.2**oc
cols=np.arange(-(h+1),h+2); rows=np.arange(-h,h+1)
def c_of(f): return (1-f)**2+f**2
fx=np.mod(u[:,None]+s[:,None]*cols[None,:],1.0); fy=np.mod(v[:,None]+s[:,None]*rows[None,:],1.0)
cx=c_of(fx); cy=c_of(fy)   # (k, 13), (k, 11)
# E[sum gx_noise^2] = sigma^2/4 * sum_i cy_i * sum_j (cx_{j+1}+cx_{j-1}) over the 11 centre columns
noise_coef=0.25*cy.sum(1)*(cx[:,2:]+cx[:,:-2]).sum(1)    # times sigma^2
cbar=(cy.mean(1)*cx[:,1:-1].mean(1))
print("noise energy coef / (n/2) by octave:", [round(float(np.median(noise_coef[oc==o]/(n/2))),3) for o in range(8)])
print("measured nxx/(n var/2):           ", [round(float(np.median((nxx/(n*nvar/2))[oc==o])),3) for o in range(8)])
m=dr>0; e=np.abs(de-dr)
def bound_old(): 
    sg=sxx-n*sig**2/2; return np.where(sg>0,np.sqrt(2*sig**2/np.maximum(sg,1e-9)),np.inf)*s
def bound_new():
    sg=sxx-noise_coef*sig**2; return np.where(sg>0,np.sqrt(2*cbar*sig**2/np.maximum(sg,1e-9)),np.inf)*s
for name,b in (("old",bound_old()),("new",bound_new())):
    rel=b/np.maximum(de,1e-3)
    for t in (0.05,0.1,0.2):
        f=rel>=t
        print(f"{name} tau {t}: flagged {100*f[m].mean():.1f}%  |dd| p50 flagged {np.median(e[m&f]):.2f} >1px {100*np.mean(e[m&f]>1):.0f}% >3px {100*np.mean(e[m&f]>3):.0f}% | kept p50 {np.median(e[m&~f]):.2f} >1px {100*np.mean(e[m&~f]>1):.0f}% ; flagged by oct", [round(100*float(f[oc==o].mean()),1) for o in range(8)])
    # matched fraction: top 7.2%
    q=np.percentile(rel[m],100-7.2); f=rel>=q
    print(f"{name} top 7.2%: |dd| p50 {np.median(e[m&f]):.2f} >1px {100*np.mean(e[m&f]>1):.0f}% >3px {100*np.mean(e[m&f]>3):.0f}%  rel depth err p50 {np.median((e/de)[m&f]):.3f}")
