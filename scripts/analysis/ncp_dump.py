"""The harness's dense NCP dump (tests/support/ncp_table.hpp, <scene>_<step>.ncp), read by
the offline studies of scripts/analysis/: int nc, then G (3nc x 3nc, column-major), g (3nc),
mu (nc) and the solver's RETURNED lambda (3nc; the dump is written after the solve, so it is
not the warm start), as doubles."""
import struct

import numpy as np


def load_ncp(path):
    """(G, g, mu, lambda) of a dump, lambda the returned forces."""
    b = open(path, 'rb').read()
    nc = struct.unpack('i', b[:4])[0]
    n = 3 * nc
    a = np.frombuffer(b[4:], dtype=np.float64)
    G = a[:n * n].reshape(n, n, order='F').copy()
    o = n * n
    g = a[o:o + n].copy(); o += n
    mu = a[o:o + nc].copy(); o += nc
    lam = a[o:o + n].copy()
    return G, g, mu, lam
