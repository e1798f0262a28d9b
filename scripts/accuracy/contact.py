"""Contact accuracy: softdiff's NCP solvers (ADMM, PGS) at several tolerances, with
and without the polish, against analytic answers.

  supports  configs/beam_supports.yaml (the beam resting on two boxes, mu = 0.5, 1 s,
            at rest from ~0.3 s): total vertical contact force of the last step against
            the weight rho g V; midspan deflection against beam theory (Euler-Bernoulli
            with the overhangs' relief and Timoshenko's shear term, simple supports), and
            against the same FE beam on ideal rollers (softdiff static, no contact), which
            separates the contact solution's error from the discretization's.
            Also frictionless (mu = 0), the supports of beam theory.
  incline   a 0.1 m cube (beam.geo with L = W = H = 0.1, n = 3: 162 tets) on the plane
            z = 0, gravity tilted by the angle a (as tests/contact/validation_contact.cpp,
            `incline`), mu = 0.5: the stick/slide threshold by bisection on a (analytic:
            tan a = mu, 26.5651 deg) and the sliding acceleration at 30 deg (analytic:
            g (sin a - mu cos a)).
"""
import csv
import math
import os

import h5py
import numpy as np

import sd
from common import file_identity, gmsh_mesh, hash_inputs, log, softdiff_bin, thread_env

G = 9.81
SUPPORTS_SCENE = "configs/beam_supports.yaml"


def plan(quick):
    if quick:
        return dict(tolerances=[1e-4, 1e-8], polish=[True, False], frictionless_tol=[1e-8],
                    bisect_iterations=8, bracket=(25.0, 28.0))
    # the supports with the polish end at 1e-15 at every tolerance: three of them suffice
    return dict(tolerances=[1e-2, 1e-4, 1e-6, 1e-8, 1e-10], polish=[True, False],
                supports_polish_tol=[1e-2, 1e-6, 1e-10],
                frictionless_tol=[1e-4, 1e-8], bisect_iterations=13, bracket=(25.0, 28.0))


def P_bracket(p):
    return p["bracket"]


def beam_theory(s, a, E=1.0e6, nu=0.45, rho=1070.0, b=0.02, h=0.02):
    """Midspan deflection of a beam on two simple supports s apart, overhanging a on
    both sides, under its own weight: Euler-Bernoulli q s^4/(384 EI) (5 - 24 a^2/s^2)
    (the span's 5 q s^4 / 384 EI less the overhangs' end moments q a^2 / 2), and the
    Timoshenko shear deflection q s^2 / (8 kappa G A), kappa = 5/6."""
    A = b * h
    I = b * h ** 3 / 12
    q = rho * G * A
    Gs = E / (2 * (1 + nu))
    eb = q * s ** 4 / (384 * E * I) * (5 - 24 * a ** 2 / s ** 2)
    shear = q * s ** 2 / (8 * (5.0 / 6.0) * Gs * A)
    return eb, shear


class Contact:
    def __init__(self, root, out, cache, threads, quick):
        self.root = root
        self.out = out
        self.cache = cache
        self.threads = threads
        self.env = thread_env(threads)
        self.quick = quick
        self.plan = plan(quick)
        self.records = []

    # -------------------------------------------------------------- one softdiff run
    def _run(self, name, scene_path, sets, reader, scene_text=None):
        folder = self.cache.folder(name)
        extra = []
        for k, v in sets:
            extra += ["--set", "%s=%s" % (k, v)]
        key = hash_inputs(scene_text if scene_text is not None else open(scene_path).read(),
                          sets, file_identity(softdiff_bin()), self.threads,
                          file_identity(os.path.join(self.root, "meshes", "beam.msh")))
        rec = self.cache.lookup(name, key)
        if rec is not None:
            return rec
        log("  softdiff %s" % name)
        r = sd.run(folder, os.path.abspath(scene_path), "out.h5", self.env, self.threads, extra)
        j = r.get("json") or {}
        ms = j.get("ms_per_step") or {}
        steps = j.get("steps") or 0
        rec = dict(name=name, wall_time_s=r["wall_s"], cpu_time_s=r["cpu_s"], peak_memory_mb=r["peak_mb"],
                   rc=r["rc"], steps=steps,
                   contact_time_s=ms.get("contact", float("nan")) * steps / 1000.0,
                   ncp_time_s=ms.get("ncp", float("nan")) * steps / 1000.0,
                   warnings=[l for l in r["stderr"].splitlines() if "warning" in l][:3])
        h5 = os.path.join(folder, "out.h5")
        if r["rc"] == 0 and os.path.exists(h5):
            with h5py.File(h5, "r") as f:
                rec.update(reader(f))
                if "solver/contact_iterations" in f:
                    rec["ncp_iterations"] = int(f["solver/contact_iterations"][:].sum())
                    rec["max_ncp_residual"] = float(f["solver/contact_residual"][1:].max())
            os.remove(h5)
        else:
            rec["status"] = "failed (exit %d): %s" % (r["rc"], r["stderr"].strip()[-300:])
        for ext in (".xmf",):
            p = os.path.join(folder, "out" + ext)
            if os.path.exists(p):
                os.remove(p)
        return self.cache.store(name, key, rec)

    # -------------------------------------------------------------- supports
    @staticmethod
    def read_supports(f):
        status = f.attrs["status"]
        status = status.decode() if isinstance(status, bytes) else str(status)
        X = f["bodies/beam/rest"][:]
        x = f["bodies/beam/x"][-1]
        off = f["contact/offsets"][:]
        k = len(f["time"]) - 1
        a, b = int(off[k]), int(off[k + 1])
        Fw = np.einsum("nij,nj->ni", f["contact/frame"][a:b], f["contact/force"][a:b])
        mid = np.abs(X[:, 0]) < 1e-9
        lam = f["contact/force"][a:b]
        carrying = lam[:, 2] > 1e-9 * max(lam[:, 2].max(), 1e-300)
        pts = f["contact/point"][a:b]
        return dict(status=status, time=float(f["time"][-1]), reaction_z=float(Fw[:, 2].sum()),
                    reaction_x=float(Fw[:, 0].sum()), contacts=b - a, carrying=int(carrying.sum()),
                    carrying_x=float(np.abs(pts[carrying, 0]).mean()) if carrying.any() else float("nan"),
                    deflection=float(-(x - X)[mid, 2].mean()),
                    max_velocity=float(np.abs(f["bodies/beam/v"][-1]).max()) if "bodies/beam/v" in f else float("nan"))

    def supports(self):
        P = self.plan
        scene = os.path.join(self.root, SUPPORTS_SCENE)
        rho, V = 1070.0, 0.2 * 0.02 * 0.02
        weight = rho * G * V
        rows = []
        for mu in (0.5, 0.0):
            tols = P["tolerances"] if mu > 0 else P["frictionless_tol"]
            pols = P["polish"] if mu > 0 else [True]
            for solver in ("admm", "pgs"):
                for pol in pols:
                    for tol in (P.get("supports_polish_tol", tols) if pol and mu > 0 else tols):
                        name = "supports_mu%g_%s_tol%g_polish%d" % (mu, solver, tol, pol)
                        sets = [("contact.solver", solver), ("contact.tolerance", repr(tol)),
                                ("contact.polish", "true" if pol else "false")]
                        if mu == 0:
                            sets += [("contact.pairs", "null"), ("contact.friction", "0.0")]
                        rec = self._run(name, scene, sets, self.read_supports)
                        rec.update(problem="supports", mu=mu, solver=solver, tolerance=tol, polish=pol)
                        rows.append(rec)
        # the FE beam on ideal rollers at the node lines that carry the load (x = +-0.085,
        # bottom): z and y fixed there, x fixed on the midspan section (symmetry), static
        roller = self.roller_reference()
        eb165, sh165 = beam_theory(0.165, 0.0175)
        eb170, sh170 = beam_theory(0.170, 0.015)
        self.supports_ref = dict(weight=weight, roller=roller, eb165=eb165, sh165=sh165, eb170=eb170, sh170=sh170)
        w_th = eb165 + sh165
        for r in rows:
            if "reaction_z" in r:
                r["reaction_error"] = abs(r["reaction_z"] - weight) / weight
                r["deflection_error_theory"] = abs(r["deflection"] - w_th) / w_th
                r["deflection_error_roller"] = abs(r["deflection"] - roller["deflection"]) / roller["deflection"]
            else:
                r["reaction_error"] = r["deflection_error_theory"] = r["deflection_error_roller"] = float("nan")
        self.records += rows
        return rows

    def roller_reference(self):
        folder = self.cache.folder("supports_roller_static")
        mesh = os.path.join(self.root, "meshes", "beam.msh")
        e = 1e-6
        scene = dict(
            name="beam on two rollers (static)",
            simulation=dict(integrator="static", gravity=[0, 0, -G],
                            static=dict(max_iterations=50, tolerance=1.0e-10, load_steps=1)),
            bodies=[dict(name="beam", mesh=os.path.relpath(mesh, folder), translate=[-0.1, -0.01, 0],
                         material=dict(law="corotational", young=1.0e6, poisson=0.45, density=1070),
                         fixed=[dict(box=[-0.085 - e, -0.011, -e, -0.085 + e, 0.011, e], axes=["y", "z"]),
                                dict(box=[0.085 - e, -0.011, -e, 0.085 + e, 0.011, e], axes=["y", "z"]),
                                dict(box=[-e, -0.011, -e, e, 0.011, 0.021], axes=["x"])])],
            output=dict(every=1))
        path = os.path.join(folder, "scene.yaml")
        text = sd.write_scene(path, scene)

        def reader(f):
            X = f["bodies/beam/rest"][:]
            x = f["bodies/beam/x"][-1]
            mid = np.abs(X[:, 0]) < 1e-9
            status = f.attrs["status"]
            return dict(status=status.decode() if isinstance(status, bytes) else str(status),
                        deflection=float(-(x - X)[mid, 2].mean()))
        return self._run("supports_roller_static", path, [], reader, scene_text=text)

    # -------------------------------------------------------------- incline
    def incline_scene(self, folder, angle, solver, tol, polish):
        mesh = gmsh_mesh(os.path.join(self.out, "meshes"), 3, L=0.1, W=0.1, H=0.1, tag="cube")
        a = math.radians(angle)
        scene = dict(
            name="cube on an incline, %.6f deg" % angle,
            simulation=dict(integrator="implicit_euler", dt=0.002, duration=0.5,
                            gravity=[G * math.sin(a), 0.0, -G * math.cos(a)], newton_iterations=1),
            bodies=[dict(name="cube", mesh=os.path.relpath(mesh, folder),
                         material=dict(law="corotational", young=1.0e6, poisson=0.3, density=1000),
                         mass="lumped", damping=dict(rayleigh_mass=0.0, rayleigh_stiffness=1.0e-3))],
            obstacles=[dict(name="floor", type="plane", normal=[0, 0, 1], offset=0.0)],
            contact=dict(enabled=True, friction=0.5, pairs=[["cube", "floor", 0.5]], margin=1.0e-3,
                         solver=solver, tolerance=tol, max_iterations=5000, polish=polish),
            output=dict(every=50, fields=["x", "v"]))
        path = os.path.join(folder, "scene.yaml")
        return path, sd.write_scene(path, scene)

    @staticmethod
    def read_incline(f):
        t = f["time"][:]
        x = f["bodies/cube/x"][:]
        v = f["bodies/cube/v"][:]
        k = {s: int(np.argmin(np.abs(t - s))) for s in (0.1, 0.3)}
        vx = lambda i: float(v[i][:, 0].mean())
        status = f.attrs["status"]
        return dict(status=status.decode() if isinstance(status, bytes) else str(status),
                    slide=float(x[-1][:, 0].mean() - x[k[0.1]][:, 0].mean()),
                    # the test's measure: mean x acceleration of the nodes over 0.1-0.5 s
                    acceleration=(vx(-1) - vx(k[0.1])) / (t[-1] - t[k[0.1]]),
                    # over 0.3-0.5 s: after the start-up transient
                    late_acceleration=(vx(-1) - vx(k[0.3])) / (t[-1] - t[k[0.3]]))

    def incline_run(self, angle, solver, tol, polish):
        name = "incline_%s_tol%g_polish%d_a%.6f" % (solver, tol, polish, angle)
        folder = self.cache.folder(name)
        path, text = self.incline_scene(folder, angle, solver, tol, polish)
        rec = self._run(name, path, [], self.read_incline, scene_text=text)
        rec["angle"] = angle
        return rec

    def incline(self):
        P = self.plan
        rows = []
        th = math.degrees(math.atan(0.5))
        a30 = G * (math.sin(math.radians(30)) - 0.5 * math.cos(math.radians(30)))
        # Gravity switched on at t = 0 makes the base slide for a few tens of ms below the
        # threshold too (the dynamic overshoot of the base shear: at 25 deg the base slides
        # 0.09 mm in 0.01-0.04 s, then sticks; at 10 deg it does not); near tan a = mu that
        # slide decays slowly
        # (deceleration g (mu cos a - sin a)). The side of the threshold is therefore read
        # from the sign of the mean x acceleration over 0.3-0.5 s: > 0 sliding on (tan a >
        # mu), < 0 a slide dying out, 0 stuck.
        slide_threshold = 5e-7   # m/s^2: |dv| = 1e-7 m/s over 0.2 s
        for solver in ("admm", "pgs"):
            for pol in P["polish"]:
                for tol in P["tolerances"]:
                    lo, hi = P["bracket"]
                    runs = []
                    r_lo = self.incline_run(lo, solver, tol, pol)
                    r_hi = self.incline_run(hi, solver, tol, pol)
                    runs += [r_lo, r_hi]
                    slides = lambda r: r["late_acceleration"] > slide_threshold
                    ok = "late_acceleration" in r_lo and "late_acceleration" in r_hi and not slides(r_lo) and slides(r_hi)
                    if ok:
                        for _ in range(P["bisect_iterations"]):
                            mid = 0.5 * (lo + hi)
                            r = self.incline_run(mid, solver, tol, pol)
                            runs.append(r)
                            if "late_acceleration" not in r:
                                ok = False
                                break
                            if slides(r):
                                hi = mid
                            else:
                                lo = mid
                    found = 0.5 * (lo + hi) if ok else float("nan")
                    # the friction coefficient the sliding run just above the threshold
                    # shows: a = g (sin a - mu cos a) while the whole base slides
                    above = [r for r in runs if "late_acceleration" in r and slides(r)]
                    mu_eff = float("nan")
                    if ok and above:
                        r_a = min(above, key=lambda r: r["angle"])
                        ang = math.radians(r_a["angle"])
                        mu_eff = (G * math.sin(ang) - r_a["late_acceleration"]) / (G * math.cos(ang))
                    r30 = self.incline_run(30.0, solver, tol, pol)
                    acc = r30.get("acceleration", float("nan"))
                    rows.append(dict(problem="incline", name="incline_%s_tol%g_polish%d" % (solver, tol, pol), mu=0.5, solver=solver, tolerance=tol, polish=pol,
                                     threshold_deg=found, threshold_bracket=hi - lo if ok else float("nan"),
                                     threshold_error_deg=abs(found - th),
                                     threshold_runs=len(runs), mu_eff=mu_eff,
                                     bracket_late_acceleration=[r_lo.get("late_acceleration"), r_hi.get("late_acceleration")],
                                     mu_eff_error=abs(mu_eff - 0.5) / 0.5,
                                     threshold_wall_time_s=sum(r["wall_time_s"] for r in runs),
                                     threshold_ncp_time_s=sum(r.get("ncp_time_s", 0) for r in runs),
                                     threshold_contact_time_s=sum(r.get("contact_time_s", 0) for r in runs),
                                     acceleration=acc, acceleration_error=abs(acc - a30) / a30,
                                     wall_time_s=r30["wall_time_s"], ncp_time_s=r30.get("ncp_time_s"),
                                     contact_time_s=r30.get("contact_time_s"),
                                     ncp_iterations=r30.get("ncp_iterations"),
                                     max_ncp_residual=r30.get("max_ncp_residual"),
                                     peak_memory_mb=r30.get("peak_memory_mb"),
                                     status=r30.get("status"), warnings=r30.get("warnings")))
        self.incline_ref = dict(threshold=th, acceleration=a30, slide_threshold=slide_threshold)
        self.records += rows
        return rows

    # -------------------------------------------------------------- outputs
    def write_csv(self, path):
        cols = ["problem", "mu", "solver", "tolerance", "polish", "quantity", "value", "analytic", "error",
                "error_vs_fe_rollers", "wall_time_s", "contact_time_s", "ncp_time_s", "ncp_iterations",
                "max_ncp_residual", "peak_memory_mb", "runs", "status"]
        S = self.supports_ref
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(cols)

            def row(r, quantity, value, analytic, error, extra=None, **kw):
                d = dict(r, quantity=quantity, value=value, analytic=analytic, error=error, runs=1)
                d.update(kw)
                if extra is not None:
                    d["error_vs_fe_rollers"] = extra
                w.writerow(["" if d.get(c) is None else ("%.6g" % d[c] if isinstance(d.get(c), float) else d[c])
                            for c in cols])
            for r in self.records:
                if r["problem"] == "supports":
                    row(r, "reaction_z_N", r.get("reaction_z"), S["weight"], r["reaction_error"])
                    row(r, "midspan_deflection_m", r.get("deflection"), S["eb165"] + S["sh165"],
                        r["deflection_error_theory"], r["deflection_error_roller"])
                else:
                    row(r, "threshold_deg", r["threshold_deg"], self.incline_ref["threshold"],
                        r["threshold_error_deg"], wall_time_s=r["threshold_wall_time_s"],
                        ncp_time_s=r["threshold_ncp_time_s"], contact_time_s=r["threshold_contact_time_s"],
                        ncp_iterations=None, max_ncp_residual=None, runs=r["threshold_runs"])
                    row(r, "mu_effective", r["mu_eff"], 0.5, r["mu_eff_error"], wall_time_s=r["threshold_wall_time_s"],
                        ncp_time_s=r["threshold_ncp_time_s"], contact_time_s=r["threshold_contact_time_s"],
                        ncp_iterations=None, max_ncp_residual=None, runs=r["threshold_runs"])
                    row(r, "acceleration_30deg_m_s2", r["acceleration"], self.incline_ref["acceleration"],
                        r["acceleration_error"])

    def plot(self, path):
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(2, 2, figsize=(13, 10))
        panels = [
            ("supports (mu = 0.5): |sum lambda_z - rho g V| / rho g V", "supports", "reaction_error", "ncp_time_s", 0.5),
            ("supports (mu = 0.5): midspan deflection vs FE rollers (solid) and beam theory (dashed)",
             "supports", "deflection_error_roller", "ncp_time_s", 0.5),
            ("incline: |mu_eff - mu| / mu, mu_eff from the sliding run just above the threshold (bisection, all runs)",
             "incline", "mu_eff_error", "threshold_ncp_time_s", 0.5),
            ("incline, 30 deg: |a - g (sin a - mu cos a)| / that", "incline", "acceleration_error", "ncp_time_s", 0.5),
        ]
        colors = {("admm", True): "C0", ("admm", False): "C1", ("pgs", True): "C2", ("pgs", False): "C3"}
        for ax, (title, prob, key, tkey, mu) in zip(axes.flat, panels):
            for (solver, pol), col in colors.items():
                rs = [r for r in self.records if r["problem"] == prob and r["solver"] == solver
                      and r["polish"] == pol and r["mu"] == mu and np.isfinite(r.get(key, np.nan))]
                rs.sort(key=lambda r: -r["tolerance"])
                if not rs:
                    continue
                t = [max(r.get(tkey) or 0, 1e-6) for r in rs]
                e = [max(r[key], 1e-17) for r in rs]
                ax.loglog(t, e, marker="o", color=col, label="%s%s" % (solver.upper(), " + polish" if pol else ""))
                for r, ti, ei in zip(rs, t, e):
                    ax.annotate("%g" % r["tolerance"], (ti, ei), fontsize=6, xytext=(2, 2), textcoords="offset points")
                if key == "deflection_error_roller":
                    e2 = [max(r["deflection_error_theory"], 1e-17) for r in rs]
                    ax.loglog(t, e2, ls="--", marker="x", color=col)
            ax.set_title(title, fontsize=8)
            ax.set_xlabel("NCP solve time [s] (summed over the run%s; labels: tolerance)"
                          % ("s" if "threshold" in tkey else ""))
            ax.set_ylabel("error")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
        fig.suptitle("softdiff contact: error vs NCP time, ADMM / PGS, with and without polish")
        fig.tight_layout()
        fig.savefig(path, dpi=120)
        plt.close(fig)

    def summary(self):
        S = self.supports_ref
        lines = []
        w = lines.append
        w("Contact accuracy (%s mode)" % ("quick" if self.quick else "full"))
        w("")
        w("Beam on two supports (%s, 100 steps of 0.01 s; values of the last step, t = 1 s):" % SUPPORTS_SCENE)
        w("  weight rho g V = %.6f N" % S["weight"])
        w("  beam theory, simple supports at the box edges (span 0.165 m, overhangs 0.0175 m): "
          "Euler-Bernoulli %.3f mm + shear %.3f mm = %.3f mm" % (1e3 * S["eb165"], 1e3 * S["sh165"],
                                                                1e3 * (S["eb165"] + S["sh165"])))
        w("  beam theory at the loaded node lines (span 0.17 m, overhangs 0.015 m): %.3f mm + %.3f mm = %.3f mm"
          % (1e3 * S["eb170"], 1e3 * S["sh170"], 1e3 * (S["eb170"] + S["sh170"])))
        rd = S["roller"].get("deflection", float("nan"))
        w("  the same FE beam (beam.msh, 3840 tets) on ideal rollers at x = +-0.085 (softdiff static): %.4f mm,"
          " %.1f %% %s beam theory at span 0.17 m: the discretization floor (linear tets, nu = 0.45)"
          % (1e3 * rd, 100 * abs(rd / (S["eb170"] + S["sh170"]) - 1),
             "below" if rd < S["eb170"] + S["sh170"] else "above"))
        w("  %-5s %-4s %-6s %-7s %12s %10s %10s %10s %9s %9s %8s %9s %8s" % (
            "mu", "solv", "polish", "tol", "reaction N", "reac.err", "defl. mm", "vs theory", "vs roller",
            "NCP s", "wall s", "NCP its", "max res"))
        for r in self.records:
            if r["problem"] != "supports":
                continue
            w("  %-5g %-4s %-6s %-7g %12.9f %10.2e %10.5f %10.3f %9.2e %9.3f %8.2f %9s %8.1e" % (
                r["mu"], r["solver"], "yes" if r["polish"] else "no", r["tolerance"], r.get("reaction_z", np.nan),
                r["reaction_error"], 1e3 * r.get("deflection", np.nan), r["deflection_error_theory"],
                r["deflection_error_roller"], r.get("ncp_time_s", np.nan), r["wall_time_s"],
                r.get("ncp_iterations", ""), r.get("max_ncp_residual", np.nan)))
        w("")
        I = self.incline_ref
        w("Cube on an incline (mu = 0.5): analytic threshold atan(0.5) = %.4f deg, sliding acceleration at 30 deg"
          " g (sin a - mu cos a) = %.6f m/s^2;\n  bisection on a: sliding = mean x acceleration over 0.3-0.5 s > %g m/s^2"
          % (I["threshold"], I["acceleration"], I["slide_threshold"]))
        w("  mu_eff: (g sin a - a_late) / (g cos a) of the sliding run nearest above the threshold")
        w("  %-4s %-6s %-7s %12s %10s %6s %9s %10s %12s %10s %9s %8s" % (
            "solv", "polish", "tol", "threshold", "error deg", "runs", "NCP s", "mu_eff-0.5", "accel 30", "rel.err",
            "NCP s", "max res"))
        for r in self.records:
            if r["problem"] != "incline":
                continue
            w("  %-4s %-6s %-7g %12.5f %10.1e %6d %9.3f %10.1e %12.7f %10.2e %9.4f %8.1e" % (
                r["solver"], "yes" if r["polish"] else "no", r["tolerance"], r["threshold_deg"],
                r["threshold_error_deg"], r["threshold_runs"], r["threshold_ncp_time_s"], r["mu_eff"] - 0.5,
                r["acceleration"],
                r["acceleration_error"], r.get("ncp_time_s") or np.nan, r.get("max_ncp_residual") or np.nan))
        bad = [r for r in self.records if r["problem"] == "incline" and not np.isfinite(r["threshold_deg"])]
        if bad:
            w("  no bisection where the bracket ends are not stuck at %g deg and sliding at %g deg (late mean x"
              " acceleration, m/s^2):" % P_bracket(self.plan))
            for r in bad:
                w("    %s: %s" % (r["name"], ", ".join("%.3g" % a if a is not None else "failed"
                                                     for a in r["bracket_late_acceleration"])))
        warn = [(r["name"], r["warnings"]) for r in self.records if r.get("warnings")]
        if warn:
            w("")
            w("Runs with warnings (first lines):")
            for n, ws in warn:
                w("  %s: %s" % (n, " | ".join(ws)))
        return "\n".join(lines)


def run(out, cache, threads, quick):
    from common import ROOT
    c = Contact(ROOT, out, cache, threads, quick)
    log("contact: beam on two supports")
    c.supports()
    log("contact: incline")
    c.incline()
    c.write_csv(os.path.join(out, "contact.csv"))
    c.plot(os.path.join(out, "contact_error_vs_time.png"))
    return c.summary()
