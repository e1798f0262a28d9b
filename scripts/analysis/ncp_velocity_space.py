#!/usr/bin/env python3
"""The offline study of docs/method.md "The self-contact impact steps: what they are"
(issue 17 item 5; a measurement tool, not part of the library): Cadoux's fixed point on a
dense NCP dumped by the harness (tests/support/ncp_table.hpp, <scene>_<step>.ncp), its
s-fixed problems  min 1/2 |y|^2  s.t.  z_i = A_i y + b_i in the second-order cone
(A_i = S_i B_i, G = B B^T from G's eigenvectors, S_i: (t1, t2, n) -> (n, mu t1, mu t2))
solved in the velocity space y by a primal-dual path-following method (AHO direction,
80 iterations). The forces are its multipliers: lambda_i = (mu x_1, mu x_2, x_0).

    /usr/bin/python3 scripts/analysis/ncp_velocity_space.py DUMP.ncp OUTER MU_SCALE [anderson] [OUT.bin]

MU_SCALE 0: the frictionless problem (one s-fixed solve); 1: the dump's friction.
"anderson": Anderson acceleration (memory 5) of the outer iteration, else plain.
OUT.bin: the best forces (raw doubles), e.g. a warm start for the library's solver.
Prints per outer iteration |F(s) - s| and the NCP residuals (those of ncp.cpp's header).
Needs numpy. ~10 s per s-fixed solve at 150 contacts.
"""
import sys
import time

import numpy as np
from ncp_dump import load_ncp as load


def proj_cone(x, mu):
    t = np.linalg.norm(x[:2]); xn = x[2]
    if t <= mu * xn: return x.copy()
    if mu * t <= -xn: return np.zeros(3)
    a = (mu * t + xn) / (mu * mu + 1)
    return np.array([mu * a * x[0] / t, mu * a * x[1] / t, a]) if t > 0 else np.array([0, 0, max(xn, 0)])


def residuals(G, g, mu, lam):
    s = G @ lam + g
    ls = max(np.abs(lam).max(), 1e-300); vs = max(np.abs(g).max(), 1e-300)
    P = D = C = 0
    for i in range(len(mu)):
        l = lam[3 * i:3 * i + 3]; v = s[3 * i:3 * i + 3].copy(); v[2] += mu[i] * np.linalg.norm(v[:2])
        P = max(P, np.linalg.norm(l - proj_cone(l, mu[i])))
        D = max(D, np.linalg.norm(proj_cone(-v, mu[i])))
        C = max(C, abs(l @ v))
    return P / ls, D / vs, C / (ls * vs)


def soc_step(u, du):  # largest t<=1 with u + t du in Q, per-cone rows (nc,3): u0 >= |u1:|
    t=np.ones(len(u))
    a=du[:,0]**2-(du[:,1:]**2).sum(1); b=u[:,0]*du[:,0]-(u[:,1:]*du[:,1:]).sum(1); c=u[:,0]**2-(u[:,1:]**2).sum(1)
    for i in range(len(u)):
        # find smallest positive root of a t^2 + 2 b t + c = 0 or u0+t du0 = 0
        cand=[]
        if du[i,0]<0: cand.append(-u[i,0]/du[i,0])
        if abs(a[i])>1e-300:
            disc=b[i]**2-a[i]*c[i]
            if disc>=0:
                for rt in ((-b[i]-np.sqrt(disc))/a[i], (-b[i]+np.sqrt(disc))/a[i]):
                    if rt>0: cand.append(rt)
        elif b[i]<0: cand.append(-c[i]/(2*b[i]))
        if cand: t[i]=min(cand)
    return t.min()
def arw(u):  # (nc,3,3)
    n=len(u); M=np.zeros((n,3,3))
    M[:,0,0]=u[:,0]; M[:,0,1:]=u[:,1:]; M[:,1:,0]=u[:,1:]
    M[:,1,1]=u[:,0]; M[:,2,2]=u[:,0]
    return M
def solve_s(B, q, mu, iters=80, tol=1e-15, y=None, x=None, z=None):
    nc=len(mu); r=B.shape[1]
    # A_i = S_i B_i, S_i: (t1,t2,n) -> (n, mu t1, mu t2)
    Bt=B.reshape(nc,3,r)
    A=np.stack([Bt[:,2],mu[:,None]*Bt[:,0],mu[:,None]*Bt[:,1]],1)  # (nc,3,r)
    Q=q.reshape(nc,3); b=np.stack([Q[:,2],mu*Q[:,0],mu*Q[:,1]],1)
    Af=A.reshape(3*nc,r)
    if y is None:
        y=np.zeros(r); z=np.tile([1.0,0,0],(nc,1)); x=np.tile([1.0,0,0],(nc,1))
    for it in range(iters):
        rd=y-Af.T@x.ravel()
        rp=(Af@y).reshape(nc,3)+b-z
        gap=(z*x).sum()/nc
        if max(np.abs(rd).max(),np.abs(rp).max())<tol and gap<tol*1e-2: break
        sig=0.1 if it>3 else 0.3
        e=np.tile([1.0,0,0],(nc,1))
        zx=np.stack([(z*x).sum(1), z[:,0]*x[:,1]+x[:,0]*z[:,1], z[:,0]*x[:,2]+x[:,0]*z[:,2]],1)
        rc=sig*gap*e-zx
        Az=arw(z); Ax=arw(x)
        Azi=np.linalg.inv(Az)
        Mx=np.einsum('iab,ibc->iac',Azi,Ax)   # Arw(z)^-1 Arw(x)
        # dz = A dy + rp ; dx = Azi rc - Mx dz ; dy - A^T dx = -rd
        # dy + A^T Mx (A dy + rp) - A^T Azi rc = -rd
        K=np.eye(r)+np.einsum('iar,iab,ibs->rs',A,Mx,A)
        rhs=-rd-np.einsum('iar,ia->r',A,np.einsum('iab,ib->ia',Mx,rp))+np.einsum('iar,ia->r',A,np.einsum('iab,ib->ia',Azi,rc))
        dy=np.linalg.solve(K,rhs)
        dz=np.einsum('iar,r->ia',A,dy)+rp
        dx=np.einsum('iab,ib->ia',Azi,rc)-np.einsum('iab,ib->ia',Mx,dz)
        t=min(1.0,0.99*soc_step(z,dz),0.99*soc_step(x,dx))
        y=y+t*dy; z=z+t*dz; x=x+t*dx
    lam=np.stack([mu*x[:,1],mu*x[:,2],x[:,0]],1).ravel()
    return y,x,z,lam,it,gap
def main():
    if len(sys.argv) < 4:
        print(__doc__); sys.exit(2)
    G, g, mu, _ = load(sys.argv[1])
    outer = int(sys.argv[2]); mu = mu * float(sys.argv[3])
    anderson = 'anderson' in sys.argv[4:]
    out = [a for a in sys.argv[4:] if a != 'anderson']
    nc = len(mu)
    w, V = np.linalg.eigh(G)
    keep = w > 1e-12 * w.max()
    B = V[:, keep] * np.sqrt(w[keep])
    s = np.zeros(3 * nc); t0 = time.time()
    best = np.inf; Fh = []; Sh = []; mem = 5
    for o in range(outer):
        y, x, z, lam, it, gap = solve_s(B, g + s, mu)
        sig = G @ lam + g
        Fs = np.zeros(3 * nc); Fs[2::3] = mu * np.linalg.norm(sig.reshape(nc, 3)[:, :2], axis=1)
        res_s = Fs - s; ds = np.abs(res_s).max(); rr = residuals(G, g, mu, lam)
        print(f"outer {o}: |F(s)-s| {ds:.2e} NCP {max(rr):.2e} (primal {rr[0]:.0e} dual {rr[1]:.0e} "
              f"complementarity {rr[2]:.0e}) {time.time() - t0:.0f} s", flush=True)
        if max(rr) < best:
            best = max(rr)
            if out: lam.tofile(out[0])
        if ds < 1e-15: break
        if not anderson:
            s = Fs
            continue
        Sh.append(s.copy()); Fh.append(res_s.copy())
        if len(Sh) > mem + 1: Sh.pop(0); Fh.pop(0)
        if len(Sh) >= 2:
            dF = np.array([Fh[j + 1] - Fh[j] for j in range(len(Fh) - 1)]).T
            dS = np.array([Sh[j + 1] - Sh[j] for j in range(len(Sh) - 1)]).T
            gam = np.linalg.lstsq(dF, res_s, rcond=None)[0]
            s = s + res_s - (dS + dF) @ gam
            s[2::3] = np.maximum(s[2::3], 0)
        else:
            s = Fs


if __name__ == '__main__':
    main()
