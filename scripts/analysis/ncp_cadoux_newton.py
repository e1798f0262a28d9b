#!/usr/bin/env python3
"""Semismooth Newton on Cadoux's fixed point F(s) - s = 0 (offline study of docs/method.md
"Newton on Cadoux's fixed point", 2026-12-04 vsnewton; issue 17 item 5; a measurement
tool, not part of the library).
F(s)_i = mu_i |sigma_T,i(s)|, sigma(s) = B y(s) + g, y(s) the s-fixed problem's unique
solution (min 1/2|y|^2 s.t. A_i y + b_i(s) in SOC), solved by ncp_velocity_space.solve_s.
F's Jacobian from the implicit function theorem on the s-fixed problem's active set:
sticking contacts (z_i = 0: A_i y + b_i = 0), sliding ones (z_i on the cone's boundary,
x_i != 0: h_i = z_i0 - |z_i1:| = 0, multiplier kappa_i = x_i0), the rest inactive.
    /usr/bin/python3 scripts/analysis/ncp_cadoux_newton.py DUMP.ncp newton ITERS [TOL_ACTIVE]
    /usr/bin/python3 scripts/analysis/ncp_cadoux_newton.py DUMP.ncp fdcheck PLAIN_ITERS
newton: from s = 0, Newton on the sliding contacts' s (the others take F(s): 0 where
sticking), backtracking on |F(s) - s|_inf (halving, 5 trials; none lower: the plain step).
fdcheck: after PLAIN_ITERS plain iterations s <- F(s), the active-set Jacobian's largest
column against central differences of F (h = 1e-5, 1e-6).
Needs numpy; each F is one interior-point solve (~10-40 s at 150 contacts).
"""
import sys, time
import numpy as np
from ncp_dump import load_ncp
from ncp_velocity_space import solve_s, residuals


def soc_data(B, q, mu):
    nc = len(mu); r = B.shape[1]
    Bt = B.reshape(nc, 3, r)
    A = np.stack([Bt[:, 2], mu[:, None] * Bt[:, 0], mu[:, None] * Bt[:, 1]], 1)
    Q = q.reshape(nc, 3); b = np.stack([Q[:, 2], mu * Q[:, 0], mu * Q[:, 1]], 1)
    return A, b


def jacobian(B, g, s, mu, y, x, z, tol):
    """dF/ds (nc x nc) at the s-fixed solution (y, x, z); the classification counts."""
    nc = len(mu); r = B.shape[1]
    A, b = soc_data(B, g + s, mu)
    zs = max(np.abs(z).max(), 1e-300); xs = max(np.abs(x).max(), 1e-300)
    stick, slide = [], []
    for i in range(nc):
        nz = np.linalg.norm(z[i]); nx = np.linalg.norm(x[i])
        if nz <= tol * zs:
            stick.append(i)
        elif z[i, 0] - np.linalg.norm(z[i, 1:]) <= tol * zs and x[i, 0] > tol * xs:
            slide.append(i)
    H = np.eye(r)
    rows = []   # constraint gradients (rows), and d(constraint)/ds (columns of nc)
    dcs = []
    for i in stick:  # s_i of a sticking contact is held (0 at a fixed point: sigma_T,i = 0)
        for a in range(3):
            rows.append(A[i, a]); dcs.append(np.zeros(nc))
    for i in slide:
        w = z[i, 1:]; nw = np.linalg.norm(w); u = w / nw
        kappa = x[i, 0]
        A1 = A[i, 1:]
        H += kappa * A1.T @ ((np.eye(2) - np.outer(u, u)) / nw) @ A1
        rows.append(A[i, 0] - u @ A1); e = np.zeros(nc); e[i] = 1.0
        dcs.append(e)
    C = np.array(rows).reshape(-1, r); Dc = np.array(dcs).reshape(-1, nc)
    m = C.shape[0]
    K = np.block([[H, -C.T], [C, np.zeros((m, m))]])
    R = np.vstack([np.zeros((r, nc)), -Dc])
    sol = np.linalg.lstsq(K, R, rcond=1e-12)[0]
    dy = sol[:r]                                  # (r x nc)
    sig = B @ y + g
    dsig = B @ dy
    J = np.zeros((nc, nc))
    for i in range(nc):
        sT = sig[3 * i:3 * i + 2]; n = np.linalg.norm(sT)
        if n > 0 and i not in stick:
            J[i] = mu[i] * (sT / n) @ dsig[3 * i:3 * i + 2]
    rs = np.linalg.matrix_rank(C[:3 * len(stick)]) if stick else 0
    return J, stick, slide, (rs, np.linalg.matrix_rank(C) if m else 0), m


def F_of(B, G, g, mu, s, tol_ip=1e-15):
    nc = len(mu)
    S = np.zeros(3 * nc); S[2::3] = s
    y, x, z, lam, it, gap = solve_s(B, g + S, mu, tol=tol_ip)
    sig = B @ y + g
    F = mu * np.linalg.norm(sig.reshape(nc, 3)[:, :2], axis=1)
    return F, y, x, z, lam, S


def fdcheck(B, G, g, mu, plain):
    nc = len(mu); s = np.zeros(nc)
    for k in range(plain):
        F = F_of(B, G, g, mu, s)[0]; print(f"plain {k}: |F(s)-s| {np.abs(F - s).max():.2e}", flush=True); s = F
    F, y, x, z, lam, S = F_of(B, G, g, mu, s)
    J, st, sl, rk, m = jacobian(B, g, S, mu, y, x, z, 1e-8)
    print(f"stick {len(st)} slide {len(sl)}; rank of the sticking rows / of all active rows {rk} of {m} rows")
    j = sl[int(np.argmax(np.abs(J[np.ix_(sl, sl)]).max(0)))]
    for h in [1e-5, 1e-6]:
        sp = s.copy(); sp[j] += h; sm = s.copy(); sm[j] -= h
        fd = (F_of(B, G, g, mu, sp)[0] - F_of(B, G, g, mu, sm)[0]) / (2 * h)
        print(f"contact {j} (s {s[j]:.3e}) h {h:.0e}: |J col| {np.abs(J[:, j]).max():.3e} |fd col| {np.abs(fd).max():.3e} "
              f"|J - fd| {np.abs(J[:, j] - fd).max():.3e}", flush=True)


def main():
    if len(sys.argv) < 4:
        print(__doc__); sys.exit(2)
    G, g, mu, _ = load_ncp(sys.argv[1]); mode = sys.argv[2]; iters = int(sys.argv[3])
    tol = float(sys.argv[4]) if len(sys.argv) > 4 else 1e-8
    nc = len(mu)
    w, V = np.linalg.eigh(G); keep = w > 1e-12 * w.max()
    B = V[:, keep] * np.sqrt(w[keep])
    if mode == 'fdcheck':
        fdcheck(B, G, g, mu, iters); return
    s = np.zeros(nc); t0 = time.time()
    F, y, x, z, lam, S = F_of(B, G, g, mu, s)
    best = np.inf
    for k in range(iters):
        res = F - s; rr = residuals(G, g, mu, lam)
        best = min(best, max(rr))
        J, st, sl, rk, m = jacobian(B, g, S, mu, y, x, z, tol)
        print(f"newton {k}: |F(s)-s| {np.abs(res).max():.2e} NCP {max(rr):.2e} (p {rr[0]:.0e} d {rr[1]:.0e} c {rr[2]:.0e}) "
              f"stick {len(st)} slide {len(sl)} constraints {m} rank stick/all {rk} |J_LL| {np.abs(J[np.ix_(sl, sl)]).max() if sl else 0:.2e} {time.time() - t0:.0f} s", flush=True)
        if np.abs(res).max() < 1e-15: break
        # Newton on the sliding contacts' s; the others take F (0 on sticking ones)
        sn = F.copy()
        if sl:
            JL = J[np.ix_(sl, sl)]
            dsl = np.linalg.solve(JL - np.eye(len(sl)), -res[sl])
        cur = np.abs(res).max(); alpha = 1.0
        for h in range(5):
            if sl: sn[sl] = np.maximum(s[sl] + alpha * dsl, 0)
            try:
                Fn, yn, xn, zn, lamn, Sn = F_of(B, G, g, mu, sn)
                if np.abs(Fn - sn).max() < cur: break
            except np.linalg.LinAlgError:
                print("   interior point failed (singular)")
            alpha *= 0.5
        else:
            alpha = 0  # no decrease: the plain fixed-point step
            sn = F.copy(); Fn, yn, xn, zn, lamn, Sn = F_of(B, G, g, mu, sn)
        s, F, y, x, z, lam, S = sn, Fn, yn, xn, zn, lamn, Sn
        if alpha < 1: print(f"   step {alpha}")
    rr = residuals(G, g, mu, lam)
    print(f"final: |F(s)-s| {np.abs(F - s).max():.2e} NCP {max(rr):.2e}, best {min(best, max(rr)):.2e}, {time.time() - t0:.0f} s")


if __name__ == '__main__':
    main()
