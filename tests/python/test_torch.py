"""softdiff.Rollout and softdiff.torch (docs/python.md "PyTorch"; issue 23 item 3).

The Rollout tests (numpy) run everywhere the module is built; the torch tests skip, with
the reason, only where PyTorch is absent (scripts/setup installs Debian's python3-torch).
"""
import os
import pathlib
import subprocess
import sys
import warnings

import softdiff  # before numpy (conftest.py: the CLI's BLAS)
import numpy as np
import pytest

try:
    import torch
    import softdiff.torch as st
except ImportError:  # pragma: no cover - scripts/setup installs python3-torch
    torch = None
needs_torch = pytest.mark.skipif(torch is None, reason="PyTorch is not installed (Debian's python3-torch; scripts/setup "
                                                       "installs it)")

ROOT = pathlib.Path(os.environ.get("SOFTDIFF_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
BEAM = ROOT / "configs" / "beam_cantilever.yaml"   # 1025 nodes, implicit Euler, gravity


def cable_beam(tmp_path, force=0.5, **overrides):
    """The cantilever beam with two straight cables along it (offset 5 mm up and 5 mm to
    the side of the axis, anchored at x = 0.19 m; tension `force` N each: about 4 mm of
    tip deflection per N at equilibrium) and a tip effector: the small scene of these tests."""
    text = BEAM.read_text().replace("../meshes/", str(ROOT / "meshes") + "/").replace(
        "      - group: clamp            # the face x = 0\n",
        "      - group: clamp\n"
        "    actuators:\n"
        f"      - {{name: top, type: cable, points: [[0.0, 0.01, 0.015], [0.19, 0.01, 0.015]], force: {force}}}\n"
        f"      - {{name: side, type: cable, points: [[0.0, 0.015, 0.01], [0.19, 0.015, 0.01]], force: {force}}}\n"
        "    effectors:\n"
        "      - {name: tip, point: [0.2, 0.01, 0.01]}\n")
    assert "name: top" in text
    path = tmp_path / "cable_beam.yaml"
    path.write_text(text)
    return softdiff.load_scene(path, overrides=overrides)


# --- softdiff.Rollout (numpy) -----------------------------------------------------------

def test_rollout_runs_the_simulators_trajectory(tmp_path):
    # Theta at the scene's values and no actuation: the Simulator's run bit for bit; the
    # schedules given as the sequence (Rollout.schedule) are the same run again.
    scene = cable_beam(tmp_path)
    r = softdiff.Rollout(scene, theta="young,poisson")
    assert r.theta_columns == ["young[beam]", "poisson[beam]"] and r.theta_groups == ["young", "poisson"]
    assert np.array_equal(r.theta_values, [1.0e6, 0.45])
    assert r.actuators == ["top", "side"] and r.num_actuators == 2 and r.num_nodes == 1025 and r.dt == 0.01
    x, v, rec = r.record(4)
    assert x.shape == v.shape == (5, 1025, 3) and rec.steps == 4 and rec.id == 1
    sim = softdiff.Simulator(scene)
    assert np.array_equal(x, sim.run(4)["beam"]) and np.array_equal(v[-1], sim.v("beam"))
    assert np.array_equal(r.schedule(4), np.full((4, 2), 0.5))
    x2, v2, rec2 = r.record(4, values=r.theta_values, actuation=r.schedule(4))
    assert np.array_equal(x2, x) and np.array_equal(v2, v) and rec2.id == 2
    # The initial state given is the scene's: the same run.
    assert np.array_equal(r.record(4, x0=x[0], v0=v[0])[0], x)
    # A body's slice of the node axis and the effector's embedding.
    assert r.nodes("beam") == slice(0, 1025, 1)
    nodes, w = r.effector("tip")
    assert nodes.shape == w.shape == (4,) and abs(w.sum() - 1) < 1e-14
    np.testing.assert_allclose(w @ x[0][nodes], [0.2, 0.01, 0.01], atol=1e-15)


def test_rollout_values_and_actuation_change_the_run(tmp_path):
    r = softdiff.Rollout(cable_beam(tmp_path, force=0), theta="young")
    base = r.record(3)[0]
    # Slack cables: a softer beam sags more under gravity (as test_overrides_change_the_motion);
    # the tension 2 N on the top cable (above the axis) lifts the tip (+z).
    assert r.record(5, values=[5.0e5])[0][-1, :, 2].min() < r.record(5, values=[2.0e6])[0][-1, :, 2].min()
    act = np.array([[2.0, 0.0]] * 3)
    nodes, w = r.effector("tip")
    assert w @ r.record(3, actuation=act)[0][-1][nodes][:, 2] > w @ base[-1][nodes][:, 2]
    # The scene's model is not changed by a run with other values.
    assert np.array_equal(r.record(3)[0], base)


def test_rollout_adjoint_against_central_differences(tmp_path):
    # l = sum_k bar_x[k] . x_k + bar_v[k] . v_k over the 5 frames of 4 steps, random
    # cotangents on every frame; the adjoint's dl/dtheta, dl/d(actuation sequence), dl/dx0
    # and dl/dv0 against central differences of l.
    # Steps and tolerances (measured on this scene): young, density h = 1e-4 of the value
    # (errors 3e-8 and 1e-8 relative; at 1e-5 the run's round-off, ~1e-14 of x amplified
    # by 1/h, gives 3e-7 and 7e-7); poisson h = 1e-5 (1.3e-7; 1e-4 gives 6e-7 of truncation:
    # lambda's 1/(1 - 2 nu) is steep at 0.45); the tensions h = 1e-4 N (errors <= 1.1e-8 of
    # the largest entry; l is nearly linear in them); x0 along a random direction h = 1e-8 m
    # (1.1e-6: a random field of node displacements strains the elements, its truncation
    # error is 2.5e-5 at 1e-7), v0 h = 1e-6 m/s (1.6e-7). Asserted: 1e-5 relative to each
    # gradient (1e-6 for the actuation, relative to its largest entry), 10x above the
    # measured error and far below a wrong term (a missing step or frame moves it by > 1e-2).
    r = softdiff.Rollout(cable_beam(tmp_path), theta="young,poisson,density")
    steps = 4
    rng = np.random.default_rng(7)
    x, v, rec = r.record(steps)
    bar_x, bar_v = rng.standard_normal(x.shape), 0.01 * rng.standard_normal(x.shape)
    g = r.adjoint(rec, bar_x, bar_v)
    assert set(g) == {"theta", "actuation", "x0", "v0", "recompute_mismatch"}
    assert g["recompute_mismatch"] == 0.0   # the sweep recomputed the recorded run bit for bit
    assert g["theta"].shape == (3,) and g["actuation"].shape == (steps, 2) and g["x0"].shape == (1025, 3)

    def loss(x, v, _rec=None):
        return (bar_x * x).sum() + (bar_v * v).sum()

    theta = r.theta_values
    for j, rel in ((0, 1e-4), (1, 1e-5), (2, 1e-4)):
        h = rel * theta[j]
        plus, minus = theta.copy(), theta.copy()
        plus[j] += h
        minus[j] -= h
        fd = (loss(*r.record(steps, values=plus)) - loss(*r.record(steps, values=minus))) / (2 * h)
        assert abs(fd - g["theta"][j]) <= 1e-5 * abs(g["theta"][j]), (r.theta_columns[j], fd, g["theta"][j])
    act, h = r.schedule(steps), 1e-4
    for s, i in ((0, 0), (1, 1), (3, 1), (2, 0)):
        plus, minus = act.copy(), act.copy()
        plus[s, i] += h
        minus[s, i] -= h
        fd = (loss(*r.record(steps, actuation=plus)) - loss(*r.record(steps, actuation=minus))) / (2 * h)
        assert abs(fd - g["actuation"][s, i]) <= 1e-6 * np.abs(g["actuation"]).max(), (s, i, fd, g["actuation"][s, i])
    d = rng.standard_normal(x[0].shape)
    for key, h, x0, v0 in (("x0", 1e-8, x[0] + 1e-8 * d, v[0]), ("v0", 1e-6, x[0], v[0] + 1e-6 * d)):
        minus = (x[0] - h * d, v[0]) if key == "x0" else (x[0], v[0] - h * d)
        fd = (loss(*r.record(steps, x0=x0, v0=v0)) - loss(*r.record(steps, x0=minus[0], v0=minus[1]))) / (2 * h)
        an = (g[key] * d).sum()
        assert abs(fd - an) <= 1e-5 * abs(an), (key, fd, an)
    # The adjoint of an earlier recording after other runs: the same numbers.
    assert np.array_equal(r.adjoint(rec, bar_x, bar_v)["theta"], g["theta"])


def test_rollout_adjoint_of_one_frame_is_the_simulators(tmp_path):
    # A cotangent on the last frame only is Simulator.adjoint's loss: the same gradient
    # (the same run and sweep; measured equal to the last bit, asserted 1e-12 relative).
    scene = cable_beam(tmp_path)
    rng = np.random.default_rng(1)
    w = rng.standard_normal((1025, 3))
    r = softdiff.Rollout(scene, theta="young")
    x, v, rec = r.record(3)
    bar = np.zeros_like(x)
    bar[-1] = w
    g = r.adjoint(rec, bar_x=bar)
    ref = softdiff.Simulator(scene).adjoint(3, bar_x=w.reshape(-1), theta="young,actuation")
    assert abs(g["theta"][0] - ref["young"][0]) <= 1e-12 * abs(ref["young"][0])
    # theta's `actuation` column (a constant offset) is the sum of the per-step cotangents.
    np.testing.assert_allclose(g["actuation"].sum(axis=0), ref["actuation"], rtol=1e-12)


def test_rollout_refusals(tmp_path):
    scene = cable_beam(tmp_path)
    with pytest.raises(ValueError, match="theta 'actuation': theta holds material parameters"):
        softdiff.Rollout(scene, theta="young,actuation")
    with pytest.raises(softdiff.SceneError, match="^theta frobnicate: unknown name"):
        softdiff.Rollout(scene, theta="frobnicate")
    with pytest.raises(ValueError, match=r'static scene .* not bound yet \(docs/python.md "Not bound yet"\)'):
        softdiff.Rollout(softdiff.load_scene(ROOT / "configs" / "beam_cantilever_static.yaml"), theta="young")
    with pytest.raises(ValueError, match=r'rigid bodies are not bound yet \(docs/python.md "Not bound yet"\)'):
        softdiff.Rollout(softdiff.load_scene(ROOT / "configs" / "rigid_stack.yaml"))
    r = softdiff.Rollout(scene, theta="young,poisson")
    with pytest.raises(ValueError, match=r"actuation: shape \(3, 2\) expected \(steps, n_actuators\), got \(3, 3\)"):
        r.record(3, actuation=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="actuation: a value is not finite"):
        r.record(1, actuation=[[np.nan, 0.0]])
    with pytest.raises(ValueError, match="values: 2 values expected, got 1"):
        r.record(1, values=[1e6])
    with pytest.raises(ValueError, match="^values: .*poisson"):
        r.record(1, values=[1e6, 0.6])
    with pytest.raises(ValueError, match="steps must be >= 0"):
        r.record(-1)
    _, _, rec = r.record(2)
    with pytest.raises(ValueError, match=r"bar_x: shape \(3, 1025, 3\) expected \(a cotangent per frame\), got \(2, 1025, 3\)"):
        r.adjoint(rec, bar_x=np.zeros((2, 1025, 3)))
    with pytest.raises(ValueError, match="the recording is another Rollout's"):
        softdiff.Rollout(scene, theta="young,poisson").adjoint(rec)
    with pytest.raises(KeyError, match="no effector 'nose'.*effectors: tip"):
        r.effector("nose")
    # A run that fails is a StepError with the CLI's message (a beam so soft that an element inverts).
    bad = softdiff.Rollout(cable_beam(tmp_path, **{"simulation.gravity": [0, 0, -5000.0]}), theta="young")
    with pytest.raises(softdiff.StepError, match="inverted element") as info:
        bad.record(3, values=[50.0])
    assert info.value.exit_code == 1
    # A refused value leaves the model as it was: the next run is the scene's.
    assert np.array_equal(r.record(2)[0], softdiff.Simulator(scene).run(2)["beam"])


def test_rollout_refuses_a_second_thread_while_it_runs(tmp_path):
    # The GIL is released during a run: another thread calling the same rollout meanwhile
    # is refused (one workspace), and the run itself is unaffected.
    import threading
    r = softdiff.Rollout(cable_beam(tmp_path))
    ref = r.record(30)[0]
    result = {}

    def work():
        while "x" not in result:
            try:
                result["x"] = r.record(30)[0]
            except RuntimeError:   # the main thread's short run came first: try again
                pass

    worker = threading.Thread(target=work)
    worker.start()
    refused = 0
    while worker.is_alive():
        try:
            r.record(0)
        except RuntimeError as e:
            assert "in use by another thread" in str(e)
            refused += 1
    worker.join()
    assert refused > 0 and np.array_equal(result["x"], ref)


# --- softdiff.torch ----------------------------------------------------------------------

@needs_torch
def test_gradcheck_young_poisson_and_the_actuation_sequence(tmp_path):
    # torch.autograd.gradcheck on the tip effector's position and velocity (mm, mm/s) at
    # every frame of a 4-step run (24 outputs) against log(young), poisson and the 4 x 2
    # tensions (10 inputs), in double precision.
    # Scaling: gradcheck perturbs every input by one eps; young (1e6 Pa) is given as
    # log(young), so eps is a relative change of young (1e-5 of 1e6 Pa = 10 Pa), and all
    # inputs are O(0.1 .. 10): log E ~ 13.8, poisson 0.45, tensions 1 N.
    # eps = 1e-5: the best measured step; central differences then err by at most 7.8e-7
    # (poisson's truncation: lambda's 1/(1 - 2 nu)) against entries up to 9.6 mm; at 1e-4
    # poisson's error is 4.3e-5, at 1e-6 the run's round-off (~1e-11 mm of tip, i.e. 5e-14
    # relative) divided by eps gives 7.8e-6. atol 1e-5 (mm per unit input) and rtol 1e-5:
    # 10x the measured error; a wrong frame or step (errors of 1e-2 and more) fails.
    scene = cable_beam(tmp_path, force=1.0)
    r = softdiff.Rollout(scene, theta="young,poisson")

    def tip(log_young, poisson, tensions):
        x, v = st.trajectory(r, torch.cat([torch.exp(log_young), poisson]), tensions, velocities=True)
        return torch.cat([st.effector(r, x, "tip")[1:], st.effector(r, v, "tip")[1:]]) * 1e3

    inputs = (torch.tensor([np.log(1.0e6)], dtype=torch.float64, requires_grad=True),
              torch.tensor([0.45], dtype=torch.float64, requires_grad=True),
              torch.ones(4, 2, dtype=torch.float64, requires_grad=True))
    with warnings.catch_warnings():
        warnings.simplefilter("error", st.RecomputeWarning)   # every backward differentiated its forward exactly
        assert torch.autograd.gradcheck(tip, inputs, eps=1e-5, atol=1e-5, rtol=1e-5)


@needs_torch
def test_gradcheck_initial_state(tmp_path):
    # x0 and v0 (3075 values each) by gradcheck's fast mode (a random projection u^T J w
    # instead of the whole Jacobian), the loss the tip's position at the last of 3 frames
    # (mm). eps = 1e-8 m for positions (a random field strains the elements: the
    # truncation error is 2.5e-5 relative at 1e-7, 1.1e-6 at 1e-8; measured on this
    # scene, test_rollout_adjoint_against_central_differences) and v0 scaled by 1e-2 so
    # that one eps is 1e-6 m/s for it; atol 1e-5, rtol 1e-4: above the measured errors.
    r = softdiff.Rollout(cable_beam(tmp_path))
    x_ref = r.record(0)[0][0]

    def tip(x0, v0_scaled):
        x = st.trajectory(r, steps=2, x0=x0, v0=v0_scaled * 1e2)
        return st.effector(r, x, "tip")[-1] * 1e3

    x0 = torch.tensor(x_ref, requires_grad=True)
    v0 = torch.zeros(1025, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(tip, (x0, v0), eps=1e-8, atol=1e-5, rtol=1e-4, fast_mode=True)


@needs_torch
def test_backward_differentiates_its_own_forward(tmp_path):
    # Two graphs from two forwards with different values: backward of the first (after
    # the second ran) is the gradient of the first run, bit for bit as if it were alone;
    # the forward's output is the Simulator's run at the same values bit for bit, and the
    # reverse sweep recomputed it exactly (no RecomputeWarning).
    scene = cable_beam(tmp_path)
    r = softdiff.Rollout(scene, theta="young")

    def grad(young, other=None):
        e = torch.tensor([young], dtype=torch.float64, requires_grad=True)
        x = st.trajectory(r, e, steps=3)
        if other is not None:   # another forward between this one and its backward
            st.trajectory(r, torch.tensor([other], dtype=torch.float64), steps=3)
        (x[1:, :, 2] ** 2).sum().backward()
        return x.detach(), e.grad.clone()

    with warnings.catch_warnings():
        warnings.simplefilter("error", st.RecomputeWarning)
        x_alone, g_alone = grad(8.0e5)
        x_mixed, g_mixed = grad(8.0e5, other=2.0e6)
    assert torch.equal(x_alone, x_mixed) and torch.equal(g_alone, g_mixed)
    ref = softdiff.Simulator(softdiff.load_scene(scene.path, overrides={"bodies.beam.material.young": 8.0e5})).run(3)
    assert np.array_equal(x_alone.numpy(), ref["beam"])
    # float32 inputs are run in double and get float32 gradients.
    e32 = torch.tensor([8.0e5], dtype=torch.float32, requires_grad=True)
    x = st.trajectory(r, e32, steps=3)
    assert x.dtype == torch.float64
    (x[1:, :, 2] ** 2).sum().backward()
    assert e32.grad.dtype == torch.float32 and torch.isclose(e32.grad.double(), g_alone, rtol=1e-6).all()


@needs_torch
def test_torch_argument_errors(tmp_path):
    r = softdiff.Rollout(cable_beam(tmp_path))
    with pytest.raises(ValueError, match="steps: give the number of steps"):
        st.trajectory(r)
    with pytest.raises(ValueError, match="steps=2 but actuation has 3 rows"):
        st.trajectory(r, actuation=torch.zeros(3, 2, dtype=torch.float64), steps=2)
    with pytest.raises(ValueError, match=r"actuation: shape \(steps, 2\) expected"):
        st.trajectory(r, actuation=torch.zeros(3, dtype=torch.float64))


def test_import_softdiff_does_not_import_torch():
    code = "import sys, softdiff; assert 'torch' not in sys.modules; print('ok')"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ))
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


@needs_torch
def test_example_trunk_tensions(tmp_path):
    # examples/python/trunk_tensions.py with 4 Adam iterations (15 steps of the Trunk, 8
    # constant tensions): the loss |tip - goal|^2 falls from 156.25 mm^2 to ~13 mm^2
    # (measured 12.6); asserted: by a factor 5 at least, and the PNG written.
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "python" / "trunk_tensions.py"), "--threads", "1",
                          "--iterations", "4", "--out", str(tmp_path)], capture_output=True, text=True, env=env,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    line = next(s for s in out.stdout.splitlines() if s.startswith("loss: "))
    first, last = float(line.split()[1]), float(line.split()[3])
    assert last < first / 5, out.stdout
    assert "final distance:" in out.stdout
    png = tmp_path / "trunk_tensions_loss.png"
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@needs_torch
def test_example_trunk_mlp(tmp_path):
    # examples/python/trunk_mlp.py with 3 goals, 6 epochs, learning rate 0.1 (10 steps of
    # the Trunk per run, 21 runs and 18 adjoints): the mean loss falls from 7.27 mm^2 to
    # ~3.4 mm^2 (measured 3.38); asserted: by a factor 1.5 at least, and the PNG written.
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "python" / "trunk_mlp.py"), "--threads", "1",
                          "--goals", "3", "--epochs", "6", "--lr", "0.1", "--out", str(tmp_path)],
                         capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    line = next(s for s in out.stdout.splitlines() if s.startswith("loss: "))
    first, last = float(line.split()[1]), float(line.split()[3])
    assert last < first / 1.5, out.stdout
    assert "held-out goal: distance" in out.stdout
    png = tmp_path / "trunk_mlp_loss.png"
    assert png.exists() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
