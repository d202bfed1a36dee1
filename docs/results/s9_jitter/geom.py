import numpy as np
def geom(Xc, f):
    x,y,z = Xc[:,0],Xc[:,1],Xc[:,2]
    J=np.zeros((len(Xc),2,6))
    J[:,0,3]=f/z; J[:,0,5]=-f*x/z**2; J[:,1,4]=f/z; J[:,1,5]=-f*y/z**2
    # rotation part (d/dw of R X ~ -[X]x)
    dP=np.zeros((len(Xc),3,3)); dP[:,0,1],dP[:,0,2]=z,-y; dP[:,1,0],dP[:,1,2]=-z,x; dP[:,2,0],dP[:,2,1]=y,-x
    Jp=np.zeros((len(Xc),2,3)); Jp[:,0,0]=f/z; Jp[:,0,2]=-f*x/z**2; Jp[:,1,1]=f/z; Jp[:,1,2]=-f*y/z**2
    J[:,:,:3]=np.einsum('nij,njk->nik',Jp,dP)
    H=np.einsum('nki,nkj->ij',J,J); C=np.linalg.inv(H)
    return np.sqrt(np.trace(C[3:,3:]))
