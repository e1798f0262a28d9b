"""Shared helpers of the accuracy benchmark: timed child processes, meshes, run cache.

Every number of the benchmark comes from a process started here: wall time from
time.perf_counter around the child, CPU time and peak resident memory from
os.wait4 on the child's pid (ru_utime + ru_stime, ru_maxrss in KiB on Linux).
"""
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
BEAM_GEO = os.path.join(ROOT, "meshes", "beam.geo")


def softdiff_bin():
    return os.environ.get("SOFTDIFF_BIN", os.path.join(ROOT, "build", "bin", "softdiff"))


def log(*args):
    print(*args, file=sys.stderr, flush=True)


def thread_env(threads):
    """Environment of a timed child: every thread pool of both tools at `threads`."""
    env = dict(os.environ)
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
              "CCX_NPROC_EQUATION_SOLVER", "CCX_NPROC_RESULTS", "CCX_NPROC_STIFFNESS",
              "NUMBER_OF_CPUS"):
        env[k] = str(threads)
    # OpenBLAS threads spin after each call (docs/performance.md); irrelevant at 1 thread
    env.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")
    env["HDF5_USE_FILE_LOCKING"] = "FALSE"
    return env


def timed_run(cmd, cwd, env, stdout_path, stderr_path, timeout=None):
    """Runs cmd; returns dict(rc, wall_s, cpu_s, peak_mb).

    The command is started through GNU time (/usr/bin/time), whose own small process
    forks the measured one: a process forked from this Python interpreter would carry
    the interpreter's resident size into its ru_maxrss (the high-water mark survives
    exec), so peak memory and CPU time are GNU time's %M, %U, %S of the tool alone.
    Wall time is measured here around the whole child.
    """
    tfile = stderr_path + ".time"
    full = ["/usr/bin/time", "-f", "%M %U %S", "-o", tfile] + list(cmd)
    with open(stdout_path, "wb") as out, open(stderr_path, "wb") as err:
        t0 = time.perf_counter()
        p = subprocess.Popen(full, cwd=cwd, env=env, stdout=out, stderr=err)
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
        wall = time.perf_counter() - t0
    rc = p.returncode
    peak = cpu = float("nan")
    try:
        for line in open(tfile):
            f = line.split()
            if len(f) == 3 and f[0].isdigit():
                peak = int(f[0]) / 1024.0
                cpu = float(f[1]) + float(f[2])
            elif line.startswith("Command exited with non-zero status"):
                rc = int(line.split()[-1])
    except OSError:
        pass
    return dict(rc=rc, wall_s=wall, cpu_s=cpu, peak_mb=peak)


class RunCache:
    """One folder per run under OUT/runs/<name>; result.json holds the measured record.

    With resume=True a run whose inputs hash to the stored value is not repeated (its
    stored record, timings included, is reused); otherwise every run is redone.
    """

    def __init__(self, out, resume):
        self.base = os.path.join(out, "runs")
        os.makedirs(self.base, exist_ok=True)
        self.resume = resume

    def folder(self, name):
        d = os.path.join(self.base, name)
        os.makedirs(d, exist_ok=True)
        return d

    def lookup(self, name, key):
        path = os.path.join(self.base, name, "result.json")
        if not self.resume or not os.path.exists(path):
            return None
        try:
            rec = json.load(open(path))
        except ValueError:
            return None
        return rec if rec.get("input_hash") == key else None

    def store(self, name, key, rec):
        rec = dict(rec)
        rec["input_hash"] = key
        with open(os.path.join(self.base, name, "result.json"), "w") as f:
            json.dump(rec, f, indent=1, default=float)
        return rec


def hash_inputs(*parts):
    h = hashlib.sha1()
    for p in parts:
        if isinstance(p, (bytes, bytearray)):
            h.update(p)
        else:
            h.update(str(p).encode())
        h.update(b"\0")
    return h.hexdigest()


def file_identity(path):
    st = os.stat(path)
    return "%s:%d:%d" % (os.path.abspath(path), st.st_size, int(st.st_mtime))


# ---------------------------------------------------------------------------
# Meshes (gmsh, from meshes/beam.geo)

def gmsh_mesh(out_dir, n, order=1, fmt="msh41", L=0.2, W=0.02, H=0.02, tag="beam"):
    """Generates beam.geo with n elements across; returns the file path (cached)."""
    os.makedirs(out_dir, exist_ok=True)
    ext = "msh" if fmt.startswith("msh") else "inp"
    name = "%s_L%g_W%g_H%g_n%d_o%d.%s" % (tag, L, W, H, n, order, ext)
    path = os.path.join(out_dir, name)
    if os.path.exists(path):
        return path
    cmd = ["gmsh", "-3", BEAM_GEO, "-setnumber", "n", str(n), "-setnumber", "L", repr(L),
           "-setnumber", "W", repr(W), "-setnumber", "H", repr(H), "-order", str(order),
           "-format", fmt, "-o", path + ".tmp"]
    r = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    if r.returncode != 0 or not os.path.exists(path + ".tmp"):
        raise RuntimeError("gmsh failed: %s\n%s" % (" ".join(cmd), r.stderr.decode()))
    os.replace(path + ".tmp", path)
    return path


def beam_tets(n, L=0.2, H=0.02):
    return 6 * n * n * int(round(n * L / H))


# ---------------------------------------------------------------------------
# Face integrals

def tri_area(X, tris):
    a = X[tris[:, 1]] - X[tris[:, 0]]
    b = X[tris[:, 2]] - X[tris[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(a, b), axis=1)


def face_mean_linear(X, U, tris):
    """Area mean of a piecewise-linear field over triangles (nodes 0-based indices)."""
    A = tri_area(X, tris)
    s = (A[:, None] * (U[tris[:, 0]] + U[tris[:, 1]] + U[tris[:, 2]]) / 3.0).sum(0)
    return s / A.sum()


def face_mean_quadratic(X, U, tris6):
    """Area mean of a quadratic field over 6-node triangles (corners a, b, c, then
    midside nodes of ab, bc, ca): the corner shape functions integrate to 0, the
    midside ones to A/3 (straight-sided triangles)."""
    A = tri_area(X, tris6[:, :3])
    s = (A[:, None] * (U[tris6[:, 3]] + U[tris6[:, 4]] + U[tris6[:, 5]]) / 3.0).sum(0)
    return s / A.sum()


def rel_error(u, ref):
    return float(np.linalg.norm(np.asarray(u) - np.asarray(ref)) / np.linalg.norm(ref))


def loglog_fit(x, y):
    """Least-squares slope p and factor c of y = c x^p."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    p, lc = np.polyfit(lx, ly, 1)
    return float(p), float(np.exp(lc))


def pareto(points):
    """Lower-left front of (time, error) points: sorted by time, error decreasing."""
    pts = sorted((t, e) for t, e in points if np.isfinite(t) and np.isfinite(e) and e > 0)
    front, best = [], np.inf
    for t, e in pts:
        if e < best:
            front.append((t, e))
            best = e
    return front


def time_at_error(front, e):
    """log-log interpolation of a Pareto front's time at error e (None outside it)."""
    if not front:
        return None
    es = [p[1] for p in front]
    if e > es[0] or e < es[-1]:
        return None
    for (t0, e0), (t1, e1) in zip(front, front[1:]):
        if e1 <= e <= e0:
            if e0 == e1:
                return t0
            w = (np.log(e) - np.log(e0)) / (np.log(e1) - np.log(e0))
            return float(np.exp(np.log(t0) + w * (np.log(t1) - np.log(t0))))
    return front[0][0] if e == es[0] else None


def which(prog):
    return shutil.which(prog)
