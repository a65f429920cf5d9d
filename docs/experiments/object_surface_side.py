"""How far, and on which side, a trained mesh lies from one object of a synthetic room.

Samples 20 000 points on the faces of GT object OBJECT_ID (area-weighted; `mesh.ply` of an
`i2sdf synth` room carries a per-face object id), finds each one's nearest vertex of each
predicted mesh (`i2sdf mesh --run RUN --out FILE.ply`, 1024 by default: vertices ~5 mm apart),
and prints the share within 2 and 5 cm, the median distance, and of the points over 5 cm off,
the share whose nearest predicted vertex lies in front of the GT face (along its normal) and
behind it (the surface carved away). No visibility culling: the figures are not eval's.

    python3 docs/experiments/object_surface_side.py ROOM/mesh.ply OBJECT_ID PRED.ply [PRED.ply …]
Needs numpy and scipy.
"""
import numpy as np, sys
from scipy.spatial import cKDTree
def read_ply(p, ids=False):
    b=open(p,'rb').read(); h=b.index(b'end_header\n')+len(b'end_header\n'); hdr=b[:h].decode()
    nv=int(hdr.split('element vertex ')[1].split()[0]); nf=int(hdr.split('element face ')[1].split()[0])
    v=np.frombuffer(b[h:h+nv*12],dtype='<f4').reshape(nv,3)
    rec=np.dtype([('n','u1'),('i','<i4',3)]+([('o','<i4')] if ids else []))
    f=np.frombuffer(b[h+nv*12:h+nv*12+nf*rec.itemsize],dtype=rec)
    return v, f
gv, gf = read_ply(sys.argv[1], ids=True)
obj=int(sys.argv[2])
tri=gv[gf['i'][gf['o']==obj]]
a=np.linalg.norm(np.cross(tri[:,1]-tri[:,0],tri[:,2]-tri[:,0]),axis=1)/2
n=np.cross(tri[:,1]-tri[:,0],tri[:,2]-tri[:,0]); n/=np.linalg.norm(n,axis=1,keepdims=True)+1e-12
rng=np.random.default_rng(0); k=rng.choice(len(tri),20000,p=a/a.sum())
r1,r2=rng.random(20000),rng.random(20000); s=np.sqrt(r1)
pts=tri[k,0]*(1-s)[:,None]+tri[k,1]*(s*(1-r2))[:,None]+tri[k,2]*(s*r2)[:,None]; nn=n[k]
lo,hi=pts.min(0)-0.3,pts.max(0)+0.3
for p in sys.argv[3:]:
    v,_=read_ply(p); sel=np.all((v>lo)&(v<hi),axis=1); v=v[sel]
    d,i=cKDTree(v).query(pts)
    sgn=np.sign(((v[i]-pts)*nn).sum(1))
    print(p, 'within 2/5 cm %.3f %.3f'%((d<0.02).mean(),(d<0.05).mean()), 'median %.3f'%np.median(d), 'of the >5 cm: in front %.2f behind %.2f'%(((d>0.05)&(sgn>0)).mean(),((d>0.05)&(sgn<0)).mean()))
