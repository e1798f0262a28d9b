"""BDF2 against implicit Euler on issue 19's dynamic beam (docs/accuracy.md, "BDF2").

The case: a 0.1 m cantilever, 10 x 10 mm section, 2.5 mm tetrahedra (meshes/beam.geo,
n = 4), clamped at x = 0, linear law (E 5 MPa, poisson 0.3, density 1000), consistent
mass, no damping, gravity switched on at t = 0 (a step load). The quantity: the area
mean of the z displacement over the x = L face, sampled every 1 ms over 0.3 s (every
10 ms for dt = 0.01); the error: max over the samples of |u - u_ref| over max |u_ref|.
The reference, on the same mesh and exact in time to what is resolved: BDF2 at
dt = 2.5e-4 / 16 (its own error is below 1/200 of BDF2's at 2.5e-4 by the second-order
scaling; the modes it cannot resolve either carry < 1e-3 of the tip motion).
Reported: the error of each integrator and dt, the observed order over dt = 1e-3, 5e-4,
2.5e-4, wall time per run, and the dt and time to reach 1% error (interpolated on the
log-log line of the last two dt). Written to the output folder: bdf2_beam.csv (one row
per run) and bdf2_error_vs_dt.png (error against dt and against wall time, one curve
per integrator).
"""
import csv
import math
import os

import numpy as np

import sd
from common import gmsh_mesh, log, softdiff_bin, thread_env

L, W, H, N = 0.1, 0.01, 0.01, 4
T_END = 0.3
DTS = [0.01, 2e-3, 1e-3, 5e-4, 2.5e-4]
REF_DT = 2.5e-4 / 16


def scene(mesh, folder, integrator, dt):
    sample = 0.01 if dt >= 0.01 else 1e-3
    body = dict(name="beam", mesh=os.path.relpath(mesh, folder),
                material=dict(law="linear", young=5.0e6, poisson=0.3, density=1000.0),
                mass="consistent", fixed=[dict(box=[-1, -1, -1, 1e-9, 1, 1])])
    sim = dict(integrator=integrator, dt=dt, duration=T_END, gravity=[0, 0, -9.81])
    return dict(name="bdf2 accuracy", simulation=sim, linear_solver="cholmod", bodies=[body],
                output=dict(every=max(1, int(round(sample / dt))), fields=["x"]))


def tip_series(out, cache, mesh, integrator, dt, threads):
    name = "bdf2beam_%s_dt%g" % (integrator, dt)
    folder = cache.folder(name)
    sd.write_scene(os.path.join(folder, "scene.yaml"), scene(mesh, folder, integrator, dt))
    log("  softdiff %s" % name)
    r = sd.run(folder, "scene.yaml", "out.h5", thread_env(threads), threads)
    if r["rc"] != 0:
        raise RuntimeError("%s failed: %s" % (name, r["stderr"]))
    series = sd.tip_mean_series(os.path.join(folder, "out.h5"))
    t = np.array([s[0] for s in series])
    uz = np.array([s[1][2] for s in series])
    return t, uz, r["wall_s"]


def run(out, cache, threads, quick):
    mesh = gmsh_mesh(os.path.join(out, "meshes"), N, L=L, W=W, H=H, tag="bdf2beam")
    dts = DTS[:3] if quick else DTS
    tr, ur, wall_ref = tip_series(out, cache, mesh, "bdf2", REF_DT if not quick else 1e-4, threads)
    ref = dict(zip(np.round(tr, 9), ur))
    peak = np.abs(ur).max()
    lines = ["BDF2 against implicit Euler: issue 19's beam (0.1 m, 2.5 mm tets, linear law, consistent mass,",
             "step load); error = max |tip z - reference| / max |reference| over 0.3 s; reference BDF2 at dt = %g"
             " (%.1f s wall)" % (REF_DT if not quick else 1e-4, wall_ref), ""]
    errors = {}
    for integ in ("implicit_euler", "bdf2"):
        for dt in dts:
            t, uz, wall = tip_series(out, cache, mesh, integ, dt, threads)
            e = max(abs(u - ref[round(tt, 9)]) for tt, u in zip(t, uz) if round(tt, 9) in ref) / peak
            errors[(integ, dt)] = (e, wall)
            lines.append("%-15s dt %-8g error %7.3f%% of the peak   %6.1f s wall" % (integ, dt, 100 * e, wall))
    lines.append("")
    with open(os.path.join(out, "bdf2_beam.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["integrator", "dt", "error", "wall_time_s"])
        for (integ, dt), (e, wall) in sorted(errors.items()):
            w.writerow([integ, dt, e, wall])
    plot(os.path.join(out, "bdf2_error_vs_dt.png"), errors, dts)
    asym = [d for d in dts if d <= 1e-3] if not quick else dts[-2:]
    for integ in ("implicit_euler", "bdf2"):
        if len(asym) >= 2:
            orders = ["%.2f" % math.log2(errors[(integ, a)][0] / errors[(integ, b)][0]) for a, b in zip(asym, asym[1:])]
            lines.append("%s observed order over dt = %s: %s" % (integ, ", ".join("%g" % d for d in asym), ", ".join(orders)))
        a, b = asym[-2], asym[-1]
        ea, eb = errors[(integ, a)][0], errors[(integ, b)][0]
        p = math.log(ea / eb) / math.log(a / b)
        dt1 = b * (0.01 / eb) ** (1 / p) if eb > 0 else float("nan")
        steps = T_END / dt1
        wall_per_step = errors[(integ, b)][1] / (T_END / b)
        lines.append("%s: 1%% error at dt ~ %.3g (%d steps, ~%.1f s wall at the measured time per step)"
                     % (integ, dt1, round(steps), steps * wall_per_step))
    return "\n".join(lines)


def plot(path, errors, dts):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for integ, style in (("implicit_euler", "o-"), ("bdf2", "s-")):
        e = [100 * errors[(integ, d)][0] for d in dts]
        t = [errors[(integ, d)][1] for d in dts]
        axes[0].loglog(dts, e, style, label=integ)
        axes[1].loglog(t, e, style, label=integ)
    axes[0].loglog(dts, [100 * errors[("bdf2", dts[-1])][0] * (d / dts[-1]) ** 2 for d in dts], "k:", label="slope 2")
    for ax in axes:
        ax.axhline(1.0, color="0.6", lw=0.8)
        ax.set_ylabel("tip error, % of the peak")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    axes[0].set_xlabel("dt (s)")
    axes[1].set_xlabel("wall time per run (s)")
    fig.suptitle("issue 19's beam: 0.1 m, 2.5 mm tets, linear law, step load, 0.3 s")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
