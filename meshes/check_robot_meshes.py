#!/usr/bin/python3
"""Compare the robot meshes generated from trunk.geo / finger.geo with the upstream meshes.

Usage: /usr/bin/python3 meshes/check_robot_meshes.py [--ref-dir DIR] [--strict]
                                                      [--trunk MSH] [--finger MSH]

Reads our MSH 4.1 ASCII files (and the MSH 2.2 ASCII references, if DIR exists; default
/work/shared/meshes) with a small parser of its own (numpy only) and prints, for each
robot and each mesh: bounding box, volume (sum of tet volumes), node and tet counts, the
normalized radius ratio 3*r_in/r_circ (1 = regular tet; min and median), the number of
tets below 0.1, and the physical groups. Then, for every cable point computed from the
published SoftRobots / CondensedFEMModel formulas, whether it lies in a tet of the mesh
and its signed distance to the boundary surface (> 0 inside, < 0 outside).
Our meshes are also checked for structural problems (tets outside the physical volume,
orphan nodes, inverted tets, missing physical groups); --strict makes these, and any
cable point of ours outside the body by more than 1e-6 mm, an error (exit code 1).
"""
import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


# ----------------------------------------------------------------------------- reading
class Mesh:
    def __init__(self):
        self.nodes = None        # (N, 3)
        self.tets = None         # (M, 4) indices into nodes
        self.tet_phys = None     # (M,) list of physical tag sets per tet (MSH 4.1) or tag
        self.tris = {}           # physical name -> (K, 3) indices
        self.names = {}          # (dim, tag) -> name
        self.vol_groups = {}     # name -> number of tets
        self.n_elements_other = 0


def _sections(path):
    sec = {}
    name = None
    buf = []
    with open(path) as f:
        for line in f:
            s = line.strip()
            if s.startswith("$End"):
                sec[name] = buf
                name = None
            elif s.startswith("$") and name is None:
                name = s[1:]
                buf = []
            elif name is not None:
                buf.append(s)
    return sec


def read_msh(path):
    sec = _sections(path)
    version = sec["MeshFormat"][0].split()[0]
    if sec["MeshFormat"][0].split()[1] != "0":
        raise SystemExit(f"{path}: binary MSH is not supported")
    m = Mesh()
    for line in sec.get("PhysicalNames", [])[1:]:
        t = line.split(maxsplit=2)
        m.names[(int(t[0]), int(t[1]))] = t[2].strip('"')
    if version.startswith("2"):
        return _read_msh2(sec, m)
    if version.startswith("4"):
        return _read_msh4(sec, m)
    raise SystemExit(f"{path}: MSH version {version} not supported")


def _read_msh2(sec, m):
    lines = sec["Nodes"]
    n = int(lines[0])
    arr = np.array([l.split() for l in lines[1:1 + n]], float)
    ids = arr[:, 0].astype(np.int64)
    idmap = np.full(ids.max() + 1, -1, np.int64)
    idmap[ids] = np.arange(n)
    m.nodes = arr[:, 1:4]
    tets, phys = [], []
    tris = {}
    lines = sec["Elements"]
    for l in lines[1:1 + int(lines[0])]:
        t = [int(x) for x in l.split()]
        etype, ntag = t[1], t[2]
        tags = t[3:3 + ntag]
        conn = t[3 + ntag:]
        if etype == 4:
            tets.append(conn)
            phys.append(tags[0] if tags else 0)
        elif etype == 2 and tags:
            tris.setdefault(tags[0], []).append(conn)
        else:
            m.n_elements_other += 1
    m.tets = idmap[np.array(tets, np.int64)]
    m.tet_phys = [{p} for p in phys]
    for p, c in tris.items():
        m.tris[m.names.get((2, p), str(p))] = idmap[np.array(c, np.int64)]
    for p in set(phys):
        m.vol_groups[m.names.get((3, p), str(p))] = phys.count(p)
    return m


def _read_msh4(sec, m):
    # $Entities: physical tags of every entity
    ent_phys = {}
    lines = sec["Entities"]
    counts = [int(x) for x in lines[0].split()]
    i = 1
    for dim, cnt in enumerate(counts):
        for _ in range(cnt):
            t = lines[i].split()
            i += 1
            tag = int(t[0])
            nphys = int(t[4] if dim == 0 else t[7])
            start = 5 if dim == 0 else 8
            ent_phys[(dim, tag)] = [int(x) for x in t[start:start + nphys]]
    # $Nodes
    lines = sec["Nodes"]
    nblocks, nnodes, _, maxtag = [int(x) for x in lines[0].split()]
    ids = np.empty(nnodes, np.int64)
    xyz = np.empty((nnodes, 3))
    i, k = 1, 0
    for _ in range(nblocks):
        _, _, param, nb = [int(x) for x in lines[i].split()]
        if param:
            raise SystemExit("parametric nodes not supported")
        i += 1
        if nb == 0:
            continue
        ids[k:k + nb] = [int(x) for x in lines[i:i + nb]]
        xyz[k:k + nb] = np.array([l.split() for l in lines[i + nb:i + 2 * nb]], float)
        i += 2 * nb
        k += nb
    idmap = np.full(maxtag + 1, -1, np.int64)
    idmap[ids] = np.arange(nnodes)
    m.nodes = xyz
    # $Elements
    lines = sec["Elements"]
    nblocks = int(lines[0].split()[0])
    i = 1
    tets, tet_phys = [], []
    for _ in range(nblocks):
        edim, etag, etype, nb = [int(x) for x in lines[i].split()]
        i += 1
        block = np.array([l.split() for l in lines[i:i + nb]], np.int64)
        i += nb
        phys = ent_phys.get((edim, etag), [])
        if etype == 4:
            tets.append(idmap[block[:, 1:5]])
            tet_phys += [set(phys)] * nb
            for p in phys:
                name = m.names.get((3, p), str(p))
                m.vol_groups[name] = m.vol_groups.get(name, 0) + nb
        elif etype == 2:
            for p in phys:
                name = m.names.get((2, p), str(p))
                prev = m.tris.get(name)
                c = idmap[block[:, 1:4]]
                m.tris[name] = c if prev is None else np.vstack([prev, c])
        else:
            m.n_elements_other += nb
    m.tets = np.vstack(tets) if tets else np.zeros((0, 4), np.int64)
    m.tet_phys = tet_phys
    return m


# ----------------------------------------------------------------------------- geometry
def tet_volumes(X, T):
    P = X[T]
    return np.einsum("ij,ij->i", np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), P[:, 3] - P[:, 0]) / 6.0


def radius_ratio(X, T):
    """Normalized radius ratio 3*r_in/r_circ (1 for the regular tet, 0 for a flat one)."""
    P = X[T]
    V = np.abs(tet_volumes(X, T))
    faces = [(1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2)]
    A = sum(0.5 * np.linalg.norm(np.cross(P[:, b] - P[:, a], P[:, c] - P[:, a]), axis=1) for a, b, c in faces)
    r_in = 3 * V / A
    # circumradius: |a|^2 (b x c) + |b|^2 (c x a) + |c|^2 (a x b) over 12 V, edges from vertex 0
    a, b, c = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]
    num = ((a * a).sum(1)[:, None] * np.cross(b, c) + (b * b).sum(1)[:, None] * np.cross(c, a)
           + (c * c).sum(1)[:, None] * np.cross(a, b))
    r_circ = np.linalg.norm(num, axis=1) / (12 * np.maximum(V, 1e-300))
    return 3 * r_in / r_circ


def boundary_faces(T):
    F = np.concatenate([T[:, [1, 2, 3]], T[:, [0, 3, 2]], T[:, [0, 1, 3]], T[:, [0, 2, 1]]])
    S = np.sort(F, axis=1)
    _, inv, cnt = np.unique(S, axis=0, return_inverse=True, return_counts=True)
    return F[cnt[inv] == 1]


def point_triangle_distance(p, A, B, C):
    """Distance from p to each triangle (A, B, C arrays (K, 3)); Ericson's closest point."""
    ab, ac, ap = B - A, C - A, p - A
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - B
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - C
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    denom = np.where(np.abs(denom) < 1e-300, 1e-300, denom)
    v = vb / denom
    w = vc / denom
    Q = A + ab * v[:, None] + ac * w[:, None]             # interior by default
    with np.errstate(divide="ignore", invalid="ignore"):
        # edge regions
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / (d1 - d3)
        Q[m] = (A + ab * t[:, None])[m]
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / (d2 - d6)
        Q[m] = (A + ac * t[:, None])[m]
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        Q[m] = (B + (C - B) * t[:, None])[m]
    # vertex regions (take precedence)
    Q[(d1 <= 0) & (d2 <= 0)] = A[(d1 <= 0) & (d2 <= 0)]
    m = (d3 >= 0) & (d4 <= d3)
    Q[m] = B[m]
    m = (d6 >= 0) & (d5 <= d6)
    Q[m] = C[m]
    return np.linalg.norm(Q - p, axis=1)


class Locator:
    def __init__(self, mesh):
        X, T = mesh.nodes, mesh.tets
        P = X[T]
        self.origin = P[:, 0]
        M = np.stack([P[:, 1] - P[:, 0], P[:, 2] - P[:, 0], P[:, 3] - P[:, 0]], axis=2)
        self.Minv = np.linalg.inv(M)
        self.lo, self.hi = P.min(1), P.max(1)
        B = boundary_faces(T)
        self.A, self.B, self.C = X[B[:, 0]], X[B[:, 1]], X[B[:, 2]]
        self.scale = np.abs(X).max()

    def locate(self, p, tol=1e-9):
        """(inside, min barycentric weight of the best tet, signed distance to the surface)."""
        tol_abs = tol * self.scale
        cand = np.nonzero(np.all((self.lo - tol_abs <= p) & (p <= self.hi + tol_abs), axis=1))[0]
        best = -np.inf
        if len(cand):
            lam = np.einsum("kij,kj->ki", self.Minv[cand], p - self.origin[cand])
            lam = np.hstack([1 - lam.sum(1, keepdims=True), lam])
            best = lam.min(1).max()
        inside = best >= -tol
        d = point_triangle_distance(p, self.A, self.B, self.C).min()
        return inside, best, d if inside else -d


# ----------------------------------------------------------------------------- cables
def trunk_cables():
    """SoftRobots Trunk cables (trunk.py formula, see meshes/README.md): 4 long, 4 short."""
    length1, length2, length_trunk = 10.0, 2.0, 195.0
    d = np.array([0.0, length2 - length1, length_trunk])
    d /= np.linalg.norm(d)
    pulls = [[0, 10, 0], [-10, 0, 0], [0, -10, 0], [10, 0, 0]]
    cables = {}
    for i in range(4):
        th = 1.57 * i                                  # upstream uses 1.57, not pi/2
        c, s = np.cos(th), np.sin(th)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        pts = [pulls[i]]
        for j in range(10):
            pts.append(R @ [d[0], d[1] * 17.5 * j + 10, d[2] * 17.5 * j + 21])
            pts.append(R @ [d[0], d[1] * 17.5 * j + 10, d[2] * 17.5 * j + 27])
        pts = np.array(pts, float)
        cables[f"cableL{i}"] = pts
        cables[f"cableS{i}"] = pts[:11]
    return cables


def finger_cables():
    """CondensedFEMModel Finger cables (Finger.py formula): pull point + 6 points each."""
    length, height, joint_height, slope, distance = 40.0, 20.0, 6.0, np.radians(45.0), 10.0
    cable_height = 2 * (height - joint_height) / 3
    standoff = cable_height * np.tan(slope)
    y = cable_height + joint_height
    cables = {}
    for name, x in (("cable1", -distance / 2), ("cable2", distance / 2)):
        pts = [[x, y, 0.0]]
        for i in range(3):
            pts.append([x, y, -standoff - length * i])
            pts.append([x, y, standoff - length * (i + 1)])
        cables[name] = np.array(pts)
    return cables


def cross_check_cables(cables, ref_dir, robot, key):
    path = os.path.join(ref_dir, "scene_parameters.json")
    if not os.path.exists(path):
        return
    js = json.load(open(path))[robot]["cables"]
    for name, pts in cables.items():
        if key == "trunk":
            ref = np.array(js["points_derived_from_formula"][name])
        else:
            ref = np.array([js[name]["pullPoint"]] + js[name]["points_derived"])
        err = np.abs(ref - pts).max()
        if err > 1e-5:
            raise SystemExit(f"cable {name}: formula and scene_parameters.json differ by {err}")


# Fixed regions of the upstream scenes (meshes/README.md): Trunk BoxROI, Finger orientedBox.
TRUNK_FIXED_BOX = [-20, -20, 0, 20, 20, 20]
FINGER_FIXED_BOX = [-11.75, -3, -3, 11.75, 26, 3]


# ----------------------------------------------------------------------------- report
def summarize(mesh, box=None):
    X, T = mesh.nodes, mesh.tets
    V = tet_volumes(X, T)
    q = radius_ratio(X, T)
    used = np.zeros(len(X), bool)
    used[T.ravel()] = True
    return {
        "nodes": len(X), "tets": len(T),
        "bbox_min": X[used].min(0), "bbox_max": X[used].max(0),
        "volume": V.sum(), "inverted": int((V <= 0).sum()),
        "q_min": q.min(), "q_med": np.median(q), "q_lt_0.1": int((q < 0.1).sum()),
        "orphans": int((~used).sum()),
        "tets_without_physical": sum(1 for s in mesh.tet_phys if not s),
        "boundary_tris": len(boundary_faces(T)),
        "nodes_in_fixed_box": "-" if box is None else
        int(np.all((X >= np.array(box[:3]) - 1e-9) & (X <= np.array(box[3:]) + 1e-9), axis=1).sum()),
    }


def fmt3(v):
    return "[" + ", ".join(f"{x:.3f}" for x in v) + "]"


def print_table(rows):
    keys = ["nodes", "tets", "bbox_min", "bbox_max", "volume", "inverted", "q_min", "q_med",
            "q_lt_0.1", "orphans", "tets_without_physical", "boundary_tris", "nodes_in_fixed_box"]
    labels = [r[0] for r in rows]
    w = max(28, *(len(l) + 2 for l in labels))
    print(f"{'':24}" + "".join(f"{l:>{w}}" for l in labels))
    for k in keys:
        cells = []
        for _, s in rows:
            v = s[k]
            if isinstance(v, np.ndarray):
                cells.append(fmt3(v))
            elif isinstance(v, float):
                cells.append(f"{v:.4g}" if k.startswith("q") else f"{v:.1f}")
            else:
                cells.append(str(v))
        print(f"{k:24}" + "".join(f"{c:>{w}}" for c in cells))


def check_robot(title, ours_path, ref_path, cables, groups, box, strict_errors, outline_ref=None):
    print(f"\n=== {title} ===")
    print(f"fixed box of the upstream scene [xmin, ymin, zmin, xmax, ymax, zmax]: {box}")
    ours = read_msh(ours_path)
    rows = [(os.path.relpath(ours_path, os.getcwd()), summarize(ours, box))]
    meshes = [("ours", ours)]
    if ref_path and os.path.exists(ref_path):
        ref = read_msh(ref_path)
        rows.append(("reference " + os.path.basename(ref_path), summarize(ref, box)))
        meshes.append(("ref", ref))
    print_table(rows)
    s = rows[0][1]
    print("physical volumes:", ours.vol_groups, " physical surfaces:",
          {k: len(v) for k, v in ours.tris.items()})
    problems = []
    for g, dim in groups:
        if dim == 3 and ours.vol_groups.get(g, 0) != len(ours.tets):
            problems.append(f"physical volume '{g}' does not hold every tet")
        if dim == 2 and g not in ours.tris:
            problems.append(f"physical surface '{g}' missing")
    for k in ("inverted", "orphans", "tets_without_physical"):
        if s[k]:
            problems.append(f"{k}: {s[k]}")
    # planar groups: report their plane and area
    for g, tri in ours.tris.items():
        P = ours.nodes[tri]
        area = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).sum()
        print(f"  surface '{g}': {len(tri)} triangles, area {area:.2f}, "
              f"z in [{P[..., 2].min():.3f}, {P[..., 2].max():.3f}]")

    # every physical triangle must be a face on the boundary of the tets
    bset = {tuple(f) for f in np.sort(boundary_faces(ours.tets), axis=1)}
    for g, tri in ours.tris.items():
        bad = sum(1 for f in np.sort(tri, axis=1) if tuple(f) not in bset)
        if bad:
            problems.append(f"surface '{g}': {bad} triangles are not boundary faces of the tets")
    if outline_ref and os.path.exists(outline_ref):
        other = (os.path.basename(outline_ref), read_msh(outline_ref))
    else:
        other = (os.path.basename(ref_path), meshes[1][1]) if len(meshes) > 1 else None
    if other:
        # outline deviation: boundary nodes of one mesh against the boundary of the other
        def dev(a, b):
            B = boundary_faces(b.tets)
            A_, B_, C_ = b.nodes[B[:, 0]], b.nodes[B[:, 1]], b.nodes[B[:, 2]]
            d = np.array([point_triangle_distance(p, A_, B_, C_).min()
                          for p in a.nodes[np.unique(boundary_faces(a.tets))]])
            return d.max(), d.mean()
        (m1, a1), (m2, a2) = dev(ours, other[1]), dev(other[1], ours)
        print(f"outline deviation from reference {other[0]}: our boundary nodes to its boundary "
              f"max {m1:.3f} mean {a1:.3f} mm; its boundary nodes to ours max {m2:.3f} mean {a2:.3f} mm")
    print("cable points: in = inside a tet (barycentric >= -1e-9), on = in and on the surface, "
          "OUT = outside; signed distance to the surface in mm (> 0 inside, < 0 outside)")
    locs = [(n, Locator(m)) for n, m in meshes]
    worst = {n: np.inf for n, _ in locs}
    n_out = {n: 0 for n, _ in locs}
    for cname, pts in cables.items():
        if cname.startswith("cableS"):
            continue  # the first 11 points of cableL<i>
        print(f"  {cname}")
        for p in pts:
            cells = []
            for n, loc in locs:
                inside, _, d = loc.locate(p)
                worst[n] = min(worst[n], d)
                if not inside:
                    n_out[n] += 1
                label = "OUT" if not inside else ("on " if abs(d) < 1e-6 else "in ")
                cells.append(f"{n}: {label} {d:+8.3f}")
            print(f"    [{p[0]:9.4f} {p[1]:9.4f} {p[2]:9.4f}]   " + "   ".join(cells))
    for n, _ in locs:
        print(f"  {n}: {n_out[n]} points outside, smallest signed distance {worst[n]:+.3f} mm")
    if worst["ours"] < -1e-6:
        problems.append(f"cable point outside our mesh by {-worst['ours']:.3g} mm")
    if problems:
        print("PROBLEMS:", "; ".join(problems))
        strict_errors += problems
    else:
        print("structure OK: every tet in the physical volume, no orphan node, no inverted tet, "
              "physical triangles on the boundary")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ref-dir", default="/work/shared/meshes")
    ap.add_argument("--strict", action="store_true")
    ap.add_argument("--trunk", default=os.path.join(HERE, "trunk.msh"), help="our trunk mesh")
    ap.add_argument("--finger", default=os.path.join(HERE, "finger.msh"), help="our finger mesh")
    a = ap.parse_args()
    np.set_printoptions(suppress=True)
    errors = []
    tc, fc = trunk_cables(), finger_cables()
    cross_check_cables(tc, a.ref_dir, "trunk", "trunk")
    cross_check_cables(fc, a.ref_dir, "finger_pianist", "finger")
    check_robot("Trunk (mm)", a.trunk,
                os.path.join(a.ref_dir, "trunk", "trunk.msh"), tc,
                [("trunk", 3), ("base", 2)], TRUNK_FIXED_BOX, errors)
    check_robot("Finger of the pianist (mm)", a.finger,
                os.path.join(a.ref_dir, "finger_pianist", "finger.msh"), fc,
                [("finger", 3), ("base", 2), ("tip", 2)], FINGER_FIXED_BOX, errors,
                outline_ref=os.path.join(a.ref_dir, "finger_pianist", "finger_fine.msh"))
    fine = os.path.join(a.ref_dir, "finger_pianist", "finger_fine.msh")
    if os.path.exists(fine):
        print("\n(reference finger_fine.msh, cavities filled, for the volume:)")
        print_table([("reference finger_fine.msh", summarize(read_msh(fine), FINGER_FIXED_BOX))])
    if a.strict and errors:
        sys.exit(1)


if __name__ == "__main__":
    main()
