"""CalculiX (ccx) side: decks from gmsh's Abaqus/CalculiX .inp meshes, runs, results.

The mesh is read from gmsh's `-format inp` output (nodes and the C3D4 / C3D10
elements only; gmsh's surface elements and sets are not used). Node sets CLAMP (x = 0)
and TIP (x = L) are built from the coordinates. C3D10 node order is checked against
CalculiX's convention (corners 1-4, then the midside nodes of edges 1-2, 2-3, 3-1,
1-4, 2-4, 3-4): every midside node must sit at the midpoint of its edge, else the
deck is refused.
"""
import os
import re

import numpy as np

from common import face_mean_linear, face_mean_quadratic, timed_run, log

# CalculiX C3D10: midside node k (0-based 4..9) on the edge between corners EDGES[k-4]
C3D10_EDGES = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
TET_FACES = [(0, 1, 2), (0, 1, 3), (1, 2, 3), (0, 2, 3)]


class InpMesh:
    def __init__(self, path, etype):
        self.etype = etype
        ids, coords, els = [], [], []
        mode = None
        for line in open(path):
            s = line.strip()
            if not s:
                continue
            if s.startswith("*"):
                u = s.upper().replace(" ", "")
                if u.startswith("*NODE") and not u.startswith("*NODEPRINT") and not u.startswith("*NODEFILE"):
                    mode = "n"
                elif u.startswith("*ELEMENT") and ("TYPE=" + etype + ",") in (u + ","):
                    mode = "e"
                else:
                    mode = None
                continue
            if mode == "n":
                p = s.split(",")
                ids.append(int(p[0]))
                coords.append([float(v) for v in p[1:4]])
            elif mode == "e":
                els.append([int(v) for v in s.split(",") if v.strip()])
        if not els:
            raise RuntimeError("%s: no %s elements" % (path, etype))
        self.node_ids = np.array(ids)
        self.X = np.array(coords)
        index = {nid: i for i, nid in enumerate(ids)}
        E = np.array(els)
        self.elem_ids = E[:, 0]
        self.conn = np.vectorize(index.get)(E[:, 1:])   # 0-based rows of X
        self._check_and_orient()
        used = np.unique(self.conn)
        self.num_nodes = len(used)        # nodes that belong to an element
        L = self.X[used, 0].max()
        self.L = L
        tol = 1e-9 * max(L, 1.0)
        self.clamp = used[np.abs(self.X[used, 0]) < tol]
        self.tip = used[np.abs(self.X[used, 0] - L) < tol]
        self.tip_faces = self._tip_faces(tol)

    def _check_and_orient(self):
        X, c = self.X, self.conn
        d = np.einsum("ij,ij->i", np.cross(X[c[:, 1]] - X[c[:, 0]], X[c[:, 2]] - X[c[:, 0]]),
                      X[c[:, 3]] - X[c[:, 0]])
        neg = d < 0
        if neg.any():   # swap corners 2 and 3 (1-based), and the midside nodes with them
            c[neg, 1], c[neg, 2] = c[neg, 2].copy(), c[neg, 1].copy()
            if self.etype == "C3D10":
                c[neg, 4], c[neg, 6] = c[neg, 6].copy(), c[neg, 4].copy()
                c[neg, 8], c[neg, 9] = c[neg, 9].copy(), c[neg, 8].copy()
        self.reoriented = int(neg.sum())
        if self.etype == "C3D10":
            h = np.linalg.norm(X[c[:, 1]] - X[c[:, 0]], axis=1).min()
            for k, (a, b) in enumerate(C3D10_EDGES):
                dev = np.linalg.norm(X[c[:, 4 + k]] - 0.5 * (X[c[:, a]] + X[c[:, b]]), axis=1).max()
                if dev > 1e-9 * h + 1e-15:
                    raise RuntimeError("C3D10 node %d is not the midpoint of corners %d-%d "
                                       "(deviation %g): node order differs from CalculiX's"
                                       % (5 + k, a + 1, b + 1, dev))

    def _tip_faces(self, tol):
        X, c = self.X, self.conn
        on_tip = np.abs(X[:, 0] - self.L) < tol
        faces = []
        for f in TET_FACES:
            sel = on_tip[c[:, f[0]]] & on_tip[c[:, f[1]]] & on_tip[c[:, f[2]]]
            for row in c[sel]:
                tri = [row[f[0]], row[f[1]], row[f[2]]]
                if self.etype == "C3D10":
                    mid = {frozenset(C3D10_EDGES[k]): row[4 + k] for k in range(6)}
                    tri += [mid[frozenset((f[0], f[1]))], mid[frozenset((f[1], f[2]))],
                            mid[frozenset((f[2], f[0]))]]
                faces.append(tri)
        return np.array(faces)

    @property
    def free_dofs(self):
        return 3 * (self.num_nodes - len(self.clamp))

    def tip_mean(self, U):
        """Area mean over the tip face of a nodal field U (rows = X rows)."""
        if self.etype == "C3D10":
            return face_mean_quadratic(self.X, U, self.tip_faces)
        return face_mean_linear(self.X, U, self.tip_faces)


def fmt(v):
    # CalculiX reads numeric fields of at most 20 characters
    return "%.14g" % v


def write_deck(path, mesh, material, procedure, g, E, nu, rho, dt=None, duration=None,
               modes=20, alpha=-0.05, print_every=100000000):
    """material: 'linear' or 'neo_hookean'; procedure: 'static', 'dynamic' (direct
    HHT, fixed increments), 'modal' (*FREQUENCY + *MODAL DYNAMIC)."""
    out = []
    w = out.append
    w("** softdiff accuracy benchmark (scripts/accuracy): %s, %s, %s" % (mesh.etype, material, procedure))
    w("*NODE, NSET=NALL")
    used = np.zeros(len(mesh.X), bool)
    used[np.unique(mesh.conn)] = True
    for i in np.nonzero(used)[0]:
        w("%d, %s, %s, %s" % (mesh.node_ids[i], fmt(mesh.X[i, 0]), fmt(mesh.X[i, 1]), fmt(mesh.X[i, 2])))
    w("*ELEMENT, TYPE=%s, ELSET=EALL" % mesh.etype)
    ids = mesh.node_ids
    for eid, row in zip(mesh.elem_ids, mesh.conn):
        w("%d, " % eid + ", ".join(str(ids[k]) for k in row))

    def nset(name, rows):
        w("*NSET, NSET=%s" % name)
        nodes = [str(ids[k]) for k in rows]
        for k in range(0, len(nodes), 12):
            w(", ".join(nodes[k:k + 12]) + ",")
    nset("CLAMP", mesh.clamp)
    nset("TIP", mesh.tip)
    w("*BOUNDARY")
    w("CLAMP, 1, 3")
    w("*MATERIAL, NAME=MAT")
    if material == "linear":
        w("*ELASTIC")
        w("%s, %s" % (fmt(E), fmt(nu)))
    else:
        mu = E / (2 * (1 + nu))
        K = E / (3 * (1 - 2 * nu))
        w("*HYPERELASTIC, NEO HOOKE")
        w("%s, %s" % (fmt(mu / 2), fmt(2 / K)))     # C10 = mu/2, D1 = 2/K
    w("*DENSITY")
    w(fmt(rho))
    w("*SOLID SECTION, ELSET=EALL, MATERIAL=MAT")
    w("*AMPLITUDE, NAME=CONST")          # gravity on at t = 0 and held (a step load)
    w("0., 1., 1000., 1.")
    nl = ", NLGEOM" if material == "neo_hookean" else ""
    grav = "EALL, GRAV, %s, 0., 0., -1." % fmt(g)
    if procedure == "static":
        w("*STEP%s, INC=1000" % nl)
        if material == "neo_hookean":
            w("*STATIC")
            w("0.25, 1., 1e-05, 0.25")   # 4 load increments (cut back automatically if needed)
        else:
            w("*STATIC")
        w("*DLOAD")
        w(grav)
    elif procedure == "dynamic":
        w("*STEP%s, INC=1000000" % nl)
        w("*DYNAMIC, DIRECT, ALPHA=%s" % fmt(alpha))
        w("%s, %s" % (fmt(dt), fmt(duration)))
        w("*DLOAD, AMPLITUDE=CONST")
        w(grav)
    elif procedure == "modal":
        if material != "linear":
            raise ValueError("modal dynamics is linear")
        w("*STEP")
        w("*FREQUENCY, STORAGE=YES")
        w(str(modes))
        w("*END STEP")
        w("*STEP, INC=1000000")
        w("*MODAL DYNAMIC")
        w("%s, %s" % (fmt(dt), fmt(duration)))
        w("*DLOAD, AMPLITUDE=CONST")
        w(grav)
    else:
        raise ValueError(procedure)
    w("*NODE PRINT, NSET=TIP, FREQUENCY=%d" % print_every)
    w("U")
    w("*END STEP")
    with open(path, "w") as f:
        f.write("\n".join(out) + "\n")


_BLOCK = re.compile(r"displacements \(vx,vy,vz\) for set TIP and time\s+(\S+)")


def read_tip_series(dat_path, mesh):
    """Every TIP displacement block of the .dat: [(time, U with rows = mesh.X rows)]."""
    text = open(dat_path).read()
    blocks = list(_BLOCK.finditer(text))
    if not blocks:
        raise RuntimeError("%s: no TIP displacement block" % dat_path)
    index = {nid: i for i, nid in enumerate(mesh.node_ids)}
    series = []
    for b in blocks:
        U = np.full((len(mesh.X), 3), np.nan)
        for line in text[b.end():].splitlines()[1:]:
            p = line.split()
            if len(p) != 4:
                if p:
                    break
                continue
            U[index[int(p[0])]] = [float(v) for v in p[1:]]
        if np.isnan(U[mesh.tip]).any():
            raise RuntimeError("%s: TIP block at t = %s incomplete" % (dat_path, b.group(1)))
        series.append((float(b.group(1)), U))
    return series


def read_tip_displacements(dat_path, mesh):
    """Last TIP displacement block of the .dat: (time, U)."""
    return read_tip_series(dat_path, mesh)[-1]


def sta_iterations(sta_path):
    """Total Newton iterations and increments from the .sta file."""
    its = incs = 0
    if not os.path.exists(sta_path):
        return None, None
    for line in open(sta_path):
        p = line.split()
        if len(p) >= 7 and p[0].isdigit() and p[1].isdigit():
            its += int(p[3])
            incs += 1
    return its, incs


def run(folder, job, env, timeout=None):
    r = timed_run(["ccx", "-i", job], folder, env, os.path.join(folder, job + ".log"),
                  os.path.join(folder, job + ".stderr"), timeout=timeout)
    # the .frd (not requested) and other scratch files are not needed afterwards
    for ext in (".frd", ".12d", ".eig"):
        p = os.path.join(folder, job + ext)
        if os.path.exists(p):
            os.remove(p)
    return r
