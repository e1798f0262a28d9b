#!/usr/bin/env python3
"""Write a dense NCP dumped by the measurement harness (tests/support/ncp_table.hpp:
<scene>_<step>.ncp, binary G g mu lambda, and <scene>_<step>.ctc, the contact records) in
the compact text form that tests/contact/test_ncp_dumps.cpp reads (load_compact_dump):
G = H W H^T, H the contacts' Jacobian on the free nodes they touch (frames rebuilt from
the normals as collision::frame_from_normal does, weights from the records), W =
H^+ G H^+T. A node is free when its columns of H lie in the range of G (a fixed node's
velocity is zero: its columns do not). Also writes an existence certificate: lambda_hat
with sigma_hat = G lambda_hat + g strictly inside every dual cone mu |s_T| <= s_N (a
linear program over an inscribed 16-gon of each cone, the margin capped at 0.1 |g|).

    /usr/bin/python3 scripts/analysis/ncp_compact_dump.py DUMP.ncp DUMP.ctc OUT.txt

Needs numpy and scipy. Prints the rank, the reconstruction error |H W H^T - G| / |G|
and the certificate's margin; refuses (exit 2) if G is not reproduced to 1e-12 or no
strictly feasible point is found.
"""
import sys

import numpy as np
from ncp_dump import load_ncp
from scipy.optimize import linprog


def frame_from_normal(n):
    k = 1 if abs(n[0]) > 0.8 else 0
    e = np.zeros(3); e[k] = 1
    t1 = e - n[k] * n
    t1 /= np.linalg.norm(t1)
    return np.column_stack([t1, np.cross(n, t1), n])


def main():
    if len(sys.argv) != 4:
        print(__doc__); sys.exit(2)
    G, g, mu, lam = load_ncp(sys.argv[1])
    C = np.atleast_2d(np.loadtxt(sys.argv[2]))
    nc = len(mu); n = 3 * nc
    if C.shape[0] != nc:
        print(f"error: {sys.argv[2]} has {C.shape[0]} records, the dump {nc} contacts"); sys.exit(2)
    nodes = C[:, 4:8].astype(int); wts = C[:, 8:12]
    frames = [frame_from_normal(C[i, 12:15] / np.linalg.norm(C[i, 12:15])) for i in range(nc)]
    used = sorted({int(nodes[i, a]) for i in range(nc) for a in range(4) if nodes[i, a] >= 0 and wts[i, a] != 0})
    w, V = np.linalg.eigh(G)
    keep = w > 1e-12 * w.max()
    P = V[:, keep]
    def columns(v):
        h = np.zeros((n, 3))
        for i in range(nc):
            for a in range(4):
                if nodes[i, a] == v and wts[i, a] != 0:
                    h[3 * i:3 * i + 3] += wts[i, a] * frames[i].T
        return h
    free = []
    for v in used:
        h = columns(v)
        if np.linalg.norm(h - P @ (P.T @ h)) <= 1e-8 * np.linalg.norm(h):
            free.append(v)
    H = np.hstack([columns(v) for v in free])
    Hp = np.linalg.pinv(H)
    W = Hp @ G @ Hp.T
    W = (W + W.T) / 2
    err = np.abs(H @ W @ H.T - G).max() / np.abs(G).max()
    print(f"{nc} contacts, {len(used)} nodes, {len(free)} free, rank G {keep.sum()}, rank H {np.linalg.matrix_rank(H)}, "
          f"|H W H^T - G| / |G| = {err:.1e}")
    if err > 1e-12:
        print("error: G is not reproduced by H W H^T"); sys.exit(2)
    # The certificate.
    B = V[:, keep] * np.sqrt(w[keep]); r = B.shape[1]; m = 16
    rows, rhs = [], []
    for i in range(nc):
        for j in range(m):
            th = 2 * np.pi * j / m
            a = mu[i] * (np.cos(th) * B[3 * i] + np.sin(th) * B[3 * i + 1]) - np.cos(np.pi / m) * B[3 * i + 2]
            rows.append(np.append(a, 1.0))
            rhs.append(-(mu[i] * (np.cos(th) * g[3 * i] + np.sin(th) * g[3 * i + 1]) - np.cos(np.pi / m) * g[3 * i + 2]))
    c = np.zeros(r + 1); c[-1] = -1
    res = linprog(c, A_ub=np.array(rows), b_ub=np.array(rhs), bounds=[(None, None)] * r + [(None, 0.1 * np.abs(g).max())],
                  method='highs')
    if res.status != 0 or res.x[-1] <= 0:
        print("error: no strictly feasible point found (no existence certificate)"); sys.exit(2)
    sig = B @ res.x[:r] + g
    lam_hat = np.linalg.pinv(G, rcond=1e-12) @ (sig - g)
    S = (G @ lam_hat + g).reshape(nc, 3)
    margin = (S[:, 2] - mu * np.linalg.norm(S[:, :2], axis=1)).min()
    print(f"certificate margin {margin:.3e} (|g| {np.abs(g).max():.3e})")
    index = {v: j for j, v in enumerate(free)}
    with open(sys.argv[3], 'w') as f:
        f.write(f"{nc} {len(free)}\n")
        for x in np.concatenate([mu, g, lam]):
            f.write(f"{x:.17g}\n")
        for i in range(nc):
            ent = [(index[nodes[i, a]], wts[i, a]) for a in range(4)
                   if nodes[i, a] >= 0 and wts[i, a] != 0 and nodes[i, a] in index]
            ent += [(-1, 0.0)] * (4 - len(ent))
            f.write(' '.join(f"{a} {b:.17g}" for a, b in ent) + ' ' +
                    ' '.join(f"{x:.17g}" for x in frames[i].T.ravel()) + "\n")
        for a in range(W.shape[0]):
            f.write(' '.join(f"{W[a, b]:.17g}" for b in range(a, W.shape[0])) + "\n")
        for x in lam_hat:
            f.write(f"{x:.17g}\n")


if __name__ == '__main__':
    main()
