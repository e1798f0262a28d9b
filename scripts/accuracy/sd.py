"""softdiff side: scenes written as YAML (format version 1), runs, HDF5 results."""
import json
import os

import h5py
import numpy as np

from common import face_mean_linear, face_mean_quadratic, softdiff_bin, timed_run


def yaml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(yaml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def to_yaml(obj, indent=0):
    """Minimal YAML writer for the scene dictionaries built here (maps, lists of maps,
    flow lists of scalars)."""
    pad = "  " * indent
    lines = []
    for k, v in obj.items():
        if isinstance(v, dict):
            lines.append("%s%s:" % (pad, k))
            lines.append(to_yaml(v, indent + 1))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            lines.append("%s%s:" % (pad, k))
            for item in v:
                sub = to_yaml(item, indent + 2).split("\n")
                sub[0] = "  " * (indent + 1) + "- " + sub[0].lstrip()
                lines.extend(sub)
        else:
            lines.append("%s%s: %s" % (pad, k, yaml_value(v)))
    return "\n".join(lines)


def write_scene(path, scene):
    text = "softdiff: 1\n" + to_yaml(scene) + "\n"
    with open(path, "w") as f:
        f.write(text)
    return text


def run(folder, scene_name, out_name, env, threads, extra=(), timeout=None):
    cmd = [softdiff_bin(), "simulate", scene_name, "-o", out_name, "--force", "--quiet",
           "--json", "--threads", str(threads)] + list(extra)
    r = timed_run(cmd, folder, env, os.path.join(folder, "stdout.json"),
                  os.path.join(folder, "stderr.txt"), timeout=timeout)
    try:
        r["json"] = json.load(open(os.path.join(folder, "stdout.json")))
    except ValueError:
        r["json"] = None
    r["stderr"] = open(os.path.join(folder, "stderr.txt"), errors="replace").read()[-2000:]
    return r


def face_mean(X, U, tris):
    """Area mean over boundary triangles: 3-node (linear field) or 6-node (the quadratic
    field of 10-node tets; softdiff's (k, 6) surface lists the corners, then the
    mid-edge nodes, as gmsh's 6-node triangle)."""
    if tris.shape[1] == 6:
        return face_mean_quadratic(X, U, tris)
    return face_mean_linear(X, U, tris)


def tip_mean_series(h5_path, body="beam"):
    """[(time, area mean over the x = max face of the displacement)] over all frames."""
    with h5py.File(h5_path, "r") as f:
        X = f["bodies/%s/rest" % body][:]
        xs = f["bodies/%s/x" % body][:]
        ts = f["time"][:]
        surf = f["bodies/%s/surface" % body][:]
    L = X[:, 0].max()
    on = np.abs(X[:, 0] - L) < 1e-9 * max(L, 1.0)
    tris = surf[on[surf].all(axis=1)]
    return [(float(t), face_mean(X, x - X, tris)) for t, x in zip(ts, xs)]


def tip_mean_displacement(h5_path, body="beam", frame=-1):
    """(time, area mean over the x = max face of the displacement, status)."""
    with h5py.File(h5_path, "r") as f:
        status = f.attrs["status"]
        status = status.decode() if isinstance(status, bytes) else str(status)
        X = f["bodies/%s/rest" % body][:]
        x = f["bodies/%s/x" % body][frame]
        t = float(f["time"][frame])
        surf = f["bodies/%s/surface" % body][:]
    L = X[:, 0].max()
    on = np.abs(X[:, 0] - L) < 1e-9 * max(L, 1.0)
    tris = surf[on[surf].all(axis=1)]
    return t, face_mean(X, x - X, tris), status
