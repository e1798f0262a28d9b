"""Tests of the Python module's step derivatives with rigid bodies and BDF2, the static
adjoint, setting the state and advance() (docs/python.md; issue 23, 2026-12-04 branch
pyrig). Each test runs a few steps of a shipped scene, shortened with overrides."""
import os
import pathlib
import warnings

import numpy as np
import pytest

import softdiff

ROOT = pathlib.Path(os.environ.get("SOFTDIFF_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
BEAM = ROOT / "configs" / "beam_cantilever.yaml"    # 1025 nodes, no contact
STACK = ROOT / "configs" / "rigid_stack.yaml"       # three free rigid boxes in contact on a floor
KEY = ROOT / "configs" / "hinged_key.yaml"          # a soft key (435 nodes) beside a hinged rigid key, no contact
STATIC = ROOT / "configs" / "beam_cantilever_static.yaml"
# The stack without contact, two boxes spinning about non-principal axes: every term of
# the free body's step Jacobian (the angular Newton residual's implicit function theorem).
FREE = {"contact.enabled": False, "bodies.middle.angular_velocity": [3.0, 1.0, 2.0],
        "bodies.top.angular_velocity": [0.0, -2.0, 5.0]}
# The rigid key's mass and inertia given explicitly (the values its density 1200 gives:
# a 22 x 140 x 12 mm box), so that central differences can move each one alone.
KEY_MASS = 1200 * 0.022 * 0.14 * 0.012
KEY_INERTIA = [KEY_MASS / 12 * (0.14 ** 2 + 0.012 ** 2), KEY_MASS / 12 * (0.022 ** 2 + 0.012 ** 2),
               KEY_MASS / 12 * (0.022 ** 2 + 0.14 ** 2)]


def stack(**overrides):
    return softdiff.load_scene(STACK, overrides=overrides)


def key(integrator, **overrides):
    o = {"simulation.integrator": integrator, "bodies.rigid_key.density": None, "bodies.rigid_key.mass": KEY_MASS,
         "bodies.rigid_key.inertia": KEY_INERTIA}
    o.update(overrides)
    return softdiff.load_scene(KEY, overrides=o)


# --- rigid states' tangents: (dp, dtheta in world axes, dv, domega), docs/python.md -----

def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def qexp(r):
    a = np.linalg.norm(r)
    return np.array([1.0, 0, 0, 0]) if a == 0 else np.concatenate([[np.cos(a / 2)], np.sin(a / 2) * r / a])


def qlog(q):
    q = -q if q[0] < 0 else q
    s = np.linalg.norm(q[1:])
    return np.zeros(3) if s == 0 else 2 * np.arctan2(s, q[0]) * q[1:] / s


def retract(pose, vel, d, e):
    """A rigid state (pose (7,), velocities (6,)) moved by e d: p + e dp, exp(e dtheta) q, ..."""
    return np.concatenate([pose[:3] + e * d[:3], qmul(qexp(e * d[3:6]), pose[3:])]), vel + e * d[6:]


def between(base, state):
    """The tangent (12,) from rigid state `base` to `state`: (p - p_b, log(q q_b^-1), ...)."""
    (bp, bv), (p, v) = base, state
    return np.concatenate([p[:3] - bp[:3], qlog(qmul(p[3:], bp[3:] * np.array([1, -1, -1, -1]))), v - bv])


def rigid_states(sim):
    return {n: (sim.x(n), sim.v(n)) for n in sim.bodies}


def set_states(sim, states):
    for n, (x, v) in states.items():
        sim.set_x(n, x)
        sim.set_v(n, v)


def split(d, bodies):
    """A dict body -> 12-vector as step_jvp's (dx, dv): 6 rows per rigid body each."""
    return (np.concatenate([d[n][:6] for n in bodies]), np.concatenate([d[n][6:] for n in bodies]))


def join(dx, dv, count):
    """step_jvp's (dx, dv) of rigid bodies only as one 12-vector per body, concatenated."""
    return np.concatenate([np.concatenate([dx[6 * r:6 * r + 6], dv[6 * r:6 * r + 6]]) for r in range(count)])


def random_rigid_direction(bodies, seed):
    rng = np.random.default_rng(seed)
    scale = np.array([1e-3] * 3 + [1e-2] * 3 + [1e-2] * 3 + [1e-1] * 3)   # m, rad, m/s, rad/s
    return {n: rng.standard_normal(12) * scale for n in bodies}


# --- step_jvp with rigid bodies: central differences of one step ----------------------

@pytest.mark.parametrize("overrides, steps", [(FREE, 5), ({}, 20), ({}, 0)])
def test_rigid_step_jvp_matches_central_differences_of_one_step(overrides, steps):
    # The rigid stack's state after `steps` steps is set into fresh simulators (set_x,
    # set_v: a restart, no contact warm start and no BDF2 history, the same for all
    # three), moved by +-e d along a random direction d of all three bodies' (pose,
    # velocity) tangents, and stepped once: (tangent(out+) - tangent(out-)) / 2e against
    # step_jvp(d). FREE: no contact (each body's 12 x 12 step Jacobian); {}: in contact
    # (the rigid rows through the contact solve: step 20 with the top box landed, step
    # 0 with the base on the floor). e = 1e-4 (relative to the direction's scale: 0.1 um,
    # 1 urad, ...): measured 5.1e-11 (free), 3.0e-10 (step 20), 3.0e-11 (step 0) of the
    # largest entry; at 1e-3 the contact case shows 1.2e-6 (a contact's mode changes),
    # at 1e-5 and 1e-6 round-off of the difference grows (to 1.2e-8). Tolerance 1e-8.
    warnings.simplefilter("ignore", softdiff.ConvergenceWarning)  # step 20 +- e: ADMM at 3e-8 (tolerance 1e-8)
    a = softdiff.Simulator(stack(**overrides))
    a.run(steps)
    start, t = rigid_states(a), a.time
    sim = softdiff.Simulator(stack(**overrides), jacobian="mass")
    sim.time = t
    set_states(sim, start)
    sim.step()
    out = rigid_states(sim)
    d = random_rigid_direction(sim.bodies, 0)
    dx, dv = sim.step_jvp(*split(d, sim.bodies))
    assert dx.shape == dv.shape == (18,)
    jvp = join(dx, dv, 3)
    e = 1e-4
    moved = []
    for sign in (1, -1):
        s = softdiff.Simulator(stack(**overrides))
        s.time = t
        set_states(s, {n: retract(*start[n], d[n], sign * e) for n in s.bodies})
        s.step()
        moved.append(rigid_states(s))
    fd = np.concatenate([(between(out[n], moved[0][n]) - between(out[n], moved[1][n])) / (2 * e) for n in sim.bodies])
    scale = np.abs(jvp).max()
    assert scale > 1e-3
    assert np.abs(fd - jvp).max() <= 1e-8 * scale


@pytest.mark.parametrize("integrator", ["implicit_euler", "bdf2"])
@pytest.mark.parametrize("name, column, value, rel_step", [
    ("young", 0, 1.0e7, 1e-4), ("mass", 0, KEY_MASS, 1e-4), ("inertia", 0, KEY_INERTIA[0], 1e-5)])
def test_key_step_jvp_matches_central_differences(integrator, name, column, value, rel_step):
    # The hinged key (a soft body beside a hinged rigid body, no contact): the tangent of
    # x_k in young (the soft key), mass and inertia.xx (the rigid key) chained through
    # step_jvp over k = 1 step (one step's JVP) and k = 4 (BDF2: steps 2-4 take the
    # previous frame's tangent as dx_prev, dv_prev) against central differences of the
    # k-step runs, on the soft key's positions and the rigid key's position and rotation
    # vector. Measured (largest error / largest entry) at h = 1e-3, 1e-4, 1e-5 of the value:
    # young 4.5e-7, 3.9e-9, 1.2e-8; mass 5.8e-9, 6.3e-11, 3.5e-10; inertia.xx 8.5e-7,
    # 8.5e-9, 3.3e-10 (its truncation is larger: h = 1e-5 for it, 1e-4 for the others),
    # both integrators alike. Tolerance 1e-7 of the largest entry. The chain also equals
    # jacobian()'s column (the forward sensitivities: the same products) to 1e-12.
    overrides = {"young": lambda h: {"bodies.soft_key.material.young": value + h},
                 "mass": lambda h: {"bodies.rigid_key.mass": value + h},
                 "inertia": lambda h: {"bodies.rigid_key.inertia": [value + h] + KEY_INERTIA[1:]}}[name]
    unit = np.zeros(6 if name == "inertia" else 1)
    unit[column] = 1.0
    rows = 3 * 435 + 6
    for steps in (1, 4):
        sim = softdiff.Simulator(key(integrator), jacobian="young,mass,inertia")
        dx, dv, px, pv = (np.zeros(rows) for _ in range(4))
        for _ in range(steps):
            sim.step()
            nx, nv = sim.step_jvp(dx=dx, dv=dv, dx_prev=px, dv_prev=pv, dtheta={name: unit})
            px, pv, dx, dv = dx, dv, nx, nv
        scale = np.abs(dx).max()
        assert scale > 0
        assert np.abs(dx - sim.jacobian()[name][:, column]).max() <= 1e-12 * scale
        assert np.abs(dv - sim.jacobian(of="v")[name][:, column]).max() <= 1e-12 * np.abs(dv).max()
        h = rel_step * value
        ends = []
        for sign in (1, -1):
            s = softdiff.Simulator(key(integrator, **overrides(sign * h)))
            s.run(steps)
            ends.append((s.x("soft_key").reshape(-1), s.x("rigid_key")))
        (xp, qp), (xm, qm) = ends
        fd = np.concatenate([(xp - xm) / (2 * h), (qp[:3] - qm[:3]) / (2 * h),
                             qlog(qmul(qp[3:], qm[3:] * np.array([1, -1, -1, -1]))) / (2 * h)])
        assert np.abs(fd - dx).max() <= 1e-7 * scale, (steps, np.abs(fd - dx).max() / scale)


@pytest.mark.parametrize("overrides, steps", [({**FREE, "simulation.integrator": "bdf2"}, 5),
                                              ({"simulation.integrator": "bdf2"}, 10)])
def test_rigid_bdf2_chain_matches_central_differences(overrides, steps):
    # BDF2's state spans two frames: the tangent of x_k from a random direction d of the
    # initial rigid states, chained through step_jvp with the previous frame's tangent
    # (dx_prev, dv_prev), against central differences of whole k-step runs from the
    # initial state moved by +-e d (set_x, set_v at frame 0: BDF2 builds its history in
    # the run). Free spinning boxes (5 steps) and the stack in contact (10 steps).
    # e = 1e-4: measured 2.4e-10 and 3.2e-11 of the largest entry (1e-5: 8.2e-10, 1.0e-9;
    # 1e-6: 1.8e-8, 1.4e-8, round-off). Tolerance 1e-8.
    warnings.simplefilter("ignore", softdiff.ConvergenceWarning)
    sim = softdiff.Simulator(stack(**overrides), jacobian="x0,v0")
    start = rigid_states(sim)
    d = random_rigid_direction(sim.bodies, 0)
    dx, dv = split(d, sim.bodies)
    px, pv = np.zeros(18), np.zeros(18)
    for _ in range(steps):
        sim.step()
        nx, nv = sim.step_jvp(dx=dx, dv=dv, dx_prev=px, dv_prev=pv)
        px, pv, dx, dv = dx, dv, nx, nv
    jvp, out = join(dx, dv, 3), rigid_states(sim)
    # The chain is jacobian()'s x0, v0 columns applied to d (the same products): 1e-12.
    d0x, d0v = split(d, sim.bodies)
    J, Jv = sim.jacobian(), sim.jacobian(of="v")
    assert np.abs(J["x0"] @ d0x + J["v0"] @ d0v - dx).max() <= 1e-12 * np.abs(dx).max()
    assert np.abs(Jv["x0"] @ d0x + Jv["v0"] @ d0v - dv).max() <= 1e-12 * np.abs(dv).max()
    e = 1e-4
    moved = []
    for sign in (1, -1):
        s = softdiff.Simulator(stack(**overrides))
        set_states(s, {n: retract(*start[n], d[n], sign * e) for n in s.bodies})
        s.run(steps)
        moved.append(rigid_states(s))
    fd = np.concatenate([(between(out[n], moved[0][n]) - between(out[n], moved[1][n])) / (2 * e) for n in sim.bodies])
    scale = np.abs(jvp).max()
    assert scale > 1e-3
    assert np.abs(fd - jvp).max() <= 1e-8 * scale


# --- BDF2 (soft): the previous frame's tangent, chained into jacobian() -----------------

def test_bdf2_step_jvp_chains_into_jacobian_and_matches_central_differences():
    # The beam under BDF2: the JVP of step k applied to (dx_{k-1}, dv_{k-1}) and the
    # previous frame's (dx_{k-2}, dv_{k-2}) of jacobian()'s columns (young, poisson) is
    # the column at step k (the same products in the library's forward sensitivities:
    # agreement to round-off, measured 0; asserted 1e-12 of the largest entry). Without
    # the previous frame's tangent the result is off by 12% of the largest entry (the
    # history matters). And the chain from frame 0 against central differences of
    # 3-step runs in young: measured 6.8e-7, 1.1e-7, 4.1e-8 of the largest entry at
    # h = 1e-3, 1e-4, 1e-5 E; h = 1e-4 E and tolerance 1e-6 as in test_softdiff.py's
    # test_jacobian_matches_central_differences (a missing term would be O(1)).
    E = 1.0e6
    bdf2 = {"simulation.integrator": "bdf2"}
    sim = softdiff.Simulator(softdiff.load_scene(BEAM, overrides=bdf2), jacobian="young,poisson")
    history = []
    for _ in range(4):
        history.append((sim.jacobian(), sim.jacobian(of="v")))
        sim.step()
    (jx1, jv1), (jx0, jv0) = history[-1], history[-2]
    for g in ("young", "poisson"):
        dx, dv = sim.step_jvp(dx=jx1[g][:, 0], dv=jv1[g][:, 0], dx_prev=jx0[g][:, 0], dv_prev=jv0[g][:, 0],
                              dtheta={g: 1.0})
        ref, refv = sim.jacobian()[g][:, 0], sim.jacobian(of="v")[g][:, 0]
        assert np.abs(dx - ref).max() <= 1e-12 * np.abs(ref).max(), g
        assert np.abs(dv - refv).max() <= 1e-12 * np.abs(refv).max(), g
        no_history, _ = sim.step_jvp(dx=jx1[g][:, 0], dv=jv1[g][:, 0], dtheta={g: 1.0})
        assert np.abs(no_history - ref).max() > 1e-3 * np.abs(ref).max(), g
    # From frame 0: three chained steps (the first is implicit Euler's: no previous frame).
    sim = softdiff.Simulator(softdiff.load_scene(BEAM, overrides=bdf2), jacobian="young")
    n3 = 3 * 1025
    dx, dv, px, pv = (np.zeros(n3) for _ in range(4))
    for _ in range(3):
        sim.step()
        nx, nv = sim.step_jvp(dx=dx, dv=dv, dx_prev=px, dv_prev=pv, dtheta={"young": 1.0})
        px, pv, dx, dv = dx, dv, nx, nv
    h = 1e-4 * E
    ends = []
    for sign in (1, -1):
        s = softdiff.Simulator(softdiff.load_scene(BEAM, overrides={**bdf2, "bodies.beam.material.young": E + sign * h}))
        s.run(3)
        ends.append(s.x("beam").reshape(-1))
    fd = (ends[0] - ends[1]) / (2 * h)
    assert np.abs(fd - dx).max() <= 1e-6 * np.abs(dx).max()


# --- step_vjp: the dot-product identity <bar, J d> = <J^T bar, d> ------------------------

def _dot_identity(sim, groups, rng, rows, with_previous):
    dx, dv = rng.standard_normal(rows), rng.standard_normal(rows)
    px, pv = (rng.standard_normal(rows), rng.standard_normal(rows)) if with_previous else (None, None)
    columns = {g: len(c) for g, c in sim.theta_columns.items()}
    dtheta = {g: rng.standard_normal(columns[g]) for g in groups}
    bar_x, bar_v = rng.standard_normal(rows), rng.standard_normal(rows)
    ox, ov = sim.step_jvp(dx=dx, dv=dv, dtheta=dtheta, dx_prev=px, dv_prev=pv)
    back = sim.step_vjp(bar_x=bar_x, bar_v=bar_v)
    assert set(back) == {"x", "v", "x_prev", "v_prev"} | set(groups)
    lhs = bar_x @ ox + bar_v @ ov
    terms = [back["x"] @ dx, back["v"] @ dv] + [back[g] @ dtheta[g] for g in groups]
    if with_previous:
        terms += [back["x_prev"] @ px, back["v_prev"] @ pv]
    else:
        assert not back["x_prev"].any() and not back["v_prev"].any()   # implicit Euler: no previous frame
    return lhs, sum(terms), max(abs(t) for t in terms)


@pytest.mark.parametrize("scene, groups, steps", [
    ("stack", ["mass", "inertia"], 20),            # rigid bodies in contact, implicit Euler
    ("stack_bdf2", ["mass", "inertia"], 20),       # in contact, BDF2 (extrapolated states)
    ("free_bdf2", ["mass", "inertia"], 5),         # no contact, BDF2 (each body's Jacobian)
    ("key", ["young", "mass", "inertia"], 4),      # soft and hinged rigid, implicit Euler
    ("key_bdf2", ["young", "mass", "inertia"], 4),
    ("beam_bdf2", ["young", "poisson", "density"], 4),
])
def test_step_vjp_is_the_transpose_of_the_jvp(scene, groups, steps):
    # Random directions of every input (the state, BDF2's previous frame, the theta
    # groups) and of the output; both sides sum products of O(1) random numbers with the
    # step Jacobian's entries, whose largest terms are 1e3-2e4 here: the round-off is
    # ~1e-13 of the largest term (measured 2.2e-16 to 9.1e-14 over these scenes),
    # asserted 1e-9 of it (a wrong or missing term would be O(1)).
    warnings.simplefilter("ignore", softdiff.ConvergenceWarning)
    scenes = {"stack": lambda: stack(), "stack_bdf2": lambda: stack(**{"simulation.integrator": "bdf2"}),
              "free_bdf2": lambda: stack(**FREE, **{"simulation.integrator": "bdf2"}),
              "key": lambda: key("implicit_euler"), "key_bdf2": lambda: key("bdf2"),
              "beam_bdf2": lambda: softdiff.load_scene(BEAM, overrides={"simulation.integrator": "bdf2",
                                                                        "bodies.beam.material.poisson": 0.3})}
    sim = softdiff.Simulator(scenes[scene](), jacobian=groups)
    sim.run(steps)
    rows = {"stack": 18, "stack_bdf2": 18, "free_bdf2": 18, "key": 3 * 435 + 6, "key_bdf2": 3 * 435 + 6,
            "beam_bdf2": 3 * 1025}[scene]
    lhs, rhs, scale = _dot_identity(sim, groups, np.random.default_rng(11), rows, scene.endswith("bdf2"))
    assert scale > 0
    assert abs(lhs - rhs) <= 1e-9 * scale, (lhs, rhs, scale)


@pytest.mark.parametrize("integrator", ["implicit_euler", "bdf2"])
def test_soft_and_rigid_in_contact(integrator):
    # configs/pads_hold.yaml: two soft pads (servo actuators) squeezing a free rigid
    # block, in contact from the first step: the soft and rigid rows through one contact
    # solve, the actuation and friction groups. At step 6 (BDF2: its extrapolated soft
    # and rigid states) the JVP of jacobian()'s columns at steps 5 and 4 is the column
    # at step 6 (the library's same products: measured 0, asserted 1e-12 of the largest
    # entry), and step_vjp is its transpose (measured 4.8e-14 and 5.2e-14 of the largest
    # term; asserted 1e-9). The forward sensitivities themselves are checked
    # against central differences in the library (check-grad, test_app).
    warnings.simplefilter("ignore", softdiff.ConvergenceWarning)
    groups = ["young", "actuation", "mass", "friction"]
    sim = softdiff.Simulator(softdiff.load_scene(ROOT / "configs" / "pads_hold.yaml",
                                                 overrides={"simulation.integrator": integrator}), jacobian=groups)
    history = []
    for _ in range(6):
        history.append((sim.jacobian(), sim.jacobian(of="v")))
        sim.step()
    (jx1, jv1), (jx0, jv0) = history[-1], history[-2]
    for g in groups:
        for c in range(jx1[g].shape[1]):
            e = np.zeros(jx1[g].shape[1])
            e[c] = 1.0
            dx, dv = sim.step_jvp(dx=jx1[g][:, c], dv=jv1[g][:, c], dx_prev=jx0[g][:, c], dv_prev=jv0[g][:, c],
                                  dtheta={g: e})
            ref, refv = sim.jacobian()[g][:, c], sim.jacobian(of="v")[g][:, c]
            assert np.abs(ref).max() > 0, (g, c)
            assert np.abs(dx - ref).max() <= 1e-12 * np.abs(ref).max(), (g, c)
            assert np.abs(dv - refv).max() <= 1e-12 * np.abs(refv).max(), (g, c)
    lhs, rhs, scale = _dot_identity(sim, groups, np.random.default_rng(3), 3 * 2050 + 6, integrator == "bdf2")
    assert abs(lhs - rhs) <= 1e-9 * scale, (lhs, rhs, scale)


def test_step_derivative_refusals_and_shapes():
    sim = softdiff.Simulator(stack(), jacobian="mass")
    with pytest.raises(ValueError, match="no step to differentiate"):
        sim.step_jvp()
    sim.step()
    with pytest.raises(ValueError, match="dx: 18 values expected, got 12"):
        sim.step_jvp(dx=np.zeros(12))
    with pytest.raises(ValueError, match="dv_prev: 18 values expected, got 3"):
        sim.step_jvp(dv_prev=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"dtheta\['mass'\]: 3 values expected, got 1"):
        sim.step_jvp(dtheta={"mass": 1.0})
    with pytest.raises(KeyError, match="not one of the simulator's theta groups"):
        sim.step_jvp(dtheta={"inertia": np.zeros(18)})
    back = sim.step_vjp(bar_x=np.ones(18))
    assert {k: v.shape for k, v in back.items()} == {"x": (18,), "v": (18,), "x_prev": (18,), "v_prev": (18,),
                                                     "mass": (3,)}
    # A static scene has no step: SceneError (a ValueError).
    st = softdiff.Simulator(softdiff.load_scene(STATIC), jacobian="young")
    st.run()
    with pytest.raises(softdiff.SceneError, match="a static scene .* has no time step"):
        st.step_jvp()
    with pytest.raises(softdiff.SceneError, match="a static scene .* has no time step"):
        st.step_vjp()


# --- adjoint() of a static scene ----------------------------------------------------------

def test_static_adjoint_is_the_jacobian_transposed():
    # l = w . x* (+ the rigid rows when there are any): the adjoint's one transposed
    # solve against jacobian()^T w from the static Jacobian (both from the implicit
    # function theorem on the same equilibrium; the Jacobian itself is checked against
    # central differences in test_softdiff.py). Round-off of two orders of summation:
    # measured 1.0e-15, 1.6e-14, 1.2e-16 relative; asserted 1e-12.
    rng = np.random.default_rng(2)
    w = rng.standard_normal(3 * 1025)
    sim = softdiff.Simulator(softdiff.load_scene(STATIC), jacobian="young,poisson,density")
    with pytest.raises(ValueError, match=r"run\(\) solves the static equilibrium first"):
        sim.adjoint(bar_x=w)
    sim.run()
    g = sim.adjoint(bar_x=w)
    assert set(g) == {"young", "poisson", "density"}
    J = sim.jacobian()
    for k in ("young", "poisson", "density"):
        f = w @ J[k][:, 0]
        assert g[k].shape == (1,) and f != 0
        assert abs(g[k][0] - f) <= 1e-12 * abs(f), (k, g[k][0], f)
    # theta= for one call, without jacobian=.
    plain = softdiff.Simulator(softdiff.load_scene(STATIC))
    plain.run()
    g2 = plain.adjoint(bar_x=w, theta="young")
    assert set(g2) == {"young"} and abs(g2["young"][0] - g["young"][0]) <= 1e-12 * abs(g["young"][0])
    with pytest.raises(ValueError, match="takes no steps"):
        sim.adjoint(4, bar_x=w)
    with pytest.raises(ValueError, match="no velocities"):
        sim.adjoint(bar_x=w, bar_v=w)
    with pytest.raises(ValueError, match="bar_x: 3075 values expected, got 2"):
        sim.adjoint(bar_x=[1.0, 2.0])
    with pytest.raises(ValueError, match=r"bar_rigid \(static: 6 per rigid body\): 0 values expected, got 6"):
        sim.adjoint(bar_x=w, bar_rigid=np.ones(6))
    with pytest.raises(softdiff.SceneError, match="^theta: 'x0' has no effect on a static equilibrium"):
        sim.adjoint(bar_x=w, theta="x0")
    with pytest.raises(ValueError, match="the number of steps is needed"):
        softdiff.Simulator(softdiff.load_scene(BEAM), jacobian="young").adjoint()


# --- setting the state -----------------------------------------------------------------------

def test_set_state_round_trips_and_a_run_from_it_is_the_run_continued():
    # A soft scene without contact under implicit Euler: the step is a function of the
    # state alone, so a fresh simulator set to the state (and time) of another after 3
    # steps runs on bit for bit as the other continues.
    a = softdiff.Simulator(softdiff.load_scene(BEAM))
    a.run(3)
    b = softdiff.Simulator(softdiff.load_scene(BEAM))
    x, v = a.x("beam"), a.v("beam")
    b.set_x("beam", x)
    b.set_v("beam", v.tolist())           # nested lists are arrays too
    b.time = a.time
    assert np.array_equal(b.x("beam"), x) and np.array_equal(b.v("beam"), v) and b.time == a.time
    assert b.steps_done == 0              # steps_done counts this simulator's steps
    ta, tb = a.run(4), b.run(4)
    assert np.array_equal(ta["beam"], tb["beam"])
    assert np.array_equal(a.v("beam"), b.v("beam"))


def test_set_state_is_a_restart():
    # Rigid bodies in contact, BDF2: after set_x/set_v the simulator runs as a fresh one
    # set to the same state does (no contact warm start, BDF2's next step its first),
    # bit for bit, and its jacobian() restarts there (x0: the identity, mass: zero).
    o = {"simulation.integrator": "bdf2"}
    warnings.simplefilter("ignore", softdiff.ConvergenceWarning)
    a = softdiff.Simulator(stack(**o), jacobian="mass,x0")
    a.run(20)
    state, t = rigid_states(a), a.time
    set_states(a, state)
    for n in a.bodies:   # a rigid pose round-trips bit for bit
        assert np.array_equal(a.x(n), state[n][0]) and np.array_equal(a.v(n), state[n][1])
    assert np.array_equal(a.jacobian()["x0"], np.eye(18)) and not a.jacobian()["mass"].any()
    with pytest.raises(ValueError, match="no step to differentiate"):
        a.step_jvp()
    b = softdiff.Simulator(stack(**o))
    b.time = t
    set_states(b, state)
    ta, tb = a.run(10), b.run(10)
    for n in a.bodies:
        assert np.array_equal(ta[n], tb[n]), n
    # BDF2's first step after the restart is implicit Euler's step of the same state.
    c = softdiff.Simulator(stack(**o))
    ie = softdiff.Simulator(stack())
    for s in (c, ie):
        s.time = t
        set_states(s, state)
        s.step()
    for n in c.bodies:
        assert np.array_equal(c.x(n), ie.x(n)), n


def test_set_state_refuses_bad_input():
    sim = softdiff.Simulator(softdiff.load_scene(BEAM))
    good = sim.x("beam")
    with pytest.raises(ValueError, match=r"set_x\('beam'\): shape \(1025, 3\) expected, got \(3075,\)"):
        sim.set_x("beam", good.reshape(-1))
    bad = good.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match=r"set_x\('beam'\): entry 16 is not finite"):
        sim.set_x("beam", bad)
    with pytest.raises(ValueError, match=r"set_v\('beam'\): entry 0 is not finite \(inf\)"):
        sim.set_v("beam", np.full((1025, 3), np.inf))
    with pytest.raises(TypeError, match="real numbers expected, got dtype complex128"):
        sim.set_x("beam", good.astype(complex))
    with pytest.raises(TypeError, match="real numbers expected"):
        sim.set_x("beam", "beam")
    moved = good + 1e-3   # node 0 is clamped (fixed)
    with pytest.raises(ValueError, match=r"set_x\('beam'\): node 0 is fixed"):
        sim.set_x("beam", moved)
    with pytest.raises(ValueError, match=r"set_v\('beam'\): node 0 is fixed \(its x velocity is 0\)"):
        sim.set_v("beam", np.ones((1025, 3)))
    with pytest.raises(KeyError, match="no body 'arm'"):
        sim.set_x("arm", good)
    with pytest.raises(ValueError, match="time: a finite number expected"):
        sim.time = float("nan")
    assert np.array_equal(sim.x("beam"), good) and sim.time == 0.0   # nothing changed
    s = softdiff.Simulator(stack())
    with pytest.raises(ValueError, match=r"set_x\('top'\): shape \(7,\) expected \(position, quaternion"):
        s.set_x("top", np.zeros(6))
    with pytest.raises(ValueError, match=r"set_x\('top'\): the quaternion .* must have unit length, got \|q\| = 2"):
        s.set_x("top", np.array([0.0, 0.0, 0.2, 2.0, 0.0, 0.0, 0.0]))
    s.set_x("top", np.array([0.0, 0.0, 0.3, 1.0 + 1e-9, 0.0, 0.0, 0.0]))   # nearly unit: normalized
    assert s.x("top")[3] == 1.0
    with pytest.raises(ValueError, match=r"set_x\('rigid_key'\): a rigid body with a joint"):
        softdiff.Simulator(key("implicit_euler")).set_x("rigid_key", np.array([0, 0, 0, 1.0, 0, 0, 0]))
    st = softdiff.Simulator(softdiff.load_scene(STATIC))
    with pytest.raises(ValueError, match="a static scene's state is the equilibrium"):
        st.set_x("beam", good)
    hub = softdiff.Simulator(softdiff.load_scene(ROOT / "configs" / "trunk_hub.yaml"))
    with pytest.raises(ValueError, match=r"set_v\('trunk'\): the body has rigidified parts \(body 'trunk' rigidify\[0\]"):
        hub.set_v("trunk", hub.v("trunk"))


# --- advance(n): the C++ loop ------------------------------------------------------------------

def test_advance_is_run_without_frames():
    a, b = softdiff.Simulator(softdiff.load_scene(BEAM)), softdiff.Simulator(softdiff.load_scene(BEAM))
    assert a.advance(6) is None
    b.run(6)
    assert a.steps_done == 6 and np.array_equal(a.x("beam"), b.x("beam")) and np.array_equal(a.v("beam"), b.v("beam"))
    with pytest.raises(ValueError, match="steps must be >= 0"):
        a.advance(-1)
    bad = softdiff.Simulator(softdiff.load_scene(BEAM, overrides={"bodies.beam.material.young": 1.0, "simulation.dt": 0.5,
                                                                          "simulation.steps": 10}))
    with pytest.raises(softdiff.StepError, match="^step 1: inverted element") as info:
        bad.advance(3)
    assert info.value.steps_done == 0 and info.value.exit_code == 1


def test_advance_warns_once_per_unconverged_step():
    # Newton capped at 2 iterations with an unreachable tolerance: every step warns, once.
    not_converging = {"simulation.newton_iterations": 2, "simulation.newton_tolerance": 1e-30}
    sim = softdiff.Simulator(softdiff.load_scene(BEAM, overrides=not_converging))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", softdiff.ConvergenceWarning)
        sim.advance(3)
    messages = [str(w.message) for w in caught if issubclass(w.category, softdiff.ConvergenceWarning)]
    assert [m.split(":")[0] for m in messages] == ["step 1", "step 2", "step 3"]
    assert sim.newton_not_converged_steps == 3 and sim.steps_done == 3
    # A warnings filter "error" stops the loop after the step that warned.
    sim = softdiff.Simulator(softdiff.load_scene(BEAM, overrides=not_converging))
    with warnings.catch_warnings():
        warnings.simplefilter("error", softdiff.ConvergenceWarning)
        with pytest.raises(softdiff.ConvergenceWarning, match="^step 1: Newton did not converge"):
            sim.advance(3)
    assert sim.steps_done == 1
