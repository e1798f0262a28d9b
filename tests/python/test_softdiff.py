"""Tests of the Python module softdiff (docs/python.md): every binding, numpy round
trips, exceptions on bad input, and the same trajectories as `softdiff simulate`, bit
for bit. Each test runs a few steps of a shipped scene (the whole file: ~10 s)."""
import os
import pathlib
import subprocess
import sys
import threading
import time
import warnings

import h5py
import numpy as np
import pytest

import softdiff

ROOT = pathlib.Path(os.environ.get("SOFTDIFF_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
BEAM = ROOT / "configs" / "beam_cantilever.yaml"    # 1025 nodes, implicit Euler, no contact
STACK = ROOT / "configs" / "rigid_stack.yaml"       # three rigid boxes in contact on a floor
STATIC = ROOT / "configs" / "beam_cantilever_static.yaml"
# The diverging beam of the CLI's test (tests/app/test_cli.cpp DivergenceExitsOneAndKeepsCompletedFrames):
# a very soft beam with a huge step inverts its elements in the first step.
DIVERGING = {"bodies.beam.material.young": 1.0, "simulation.dt": 0.5, "simulation.steps": 10}


def beam(**overrides):
    return softdiff.load_scene(BEAM, overrides=overrides)


# --- import and types ---------------------------------------------------------------

def test_import_exposes_the_api():
    assert softdiff.__version__.count(".") == 2
    for name in ("load_scene", "Simulator", "Scene", "SceneError", "StepError", "ConvergenceWarning", "SceneWarning",
                 "thread_plan"):
        assert hasattr(softdiff, name), name
    assert issubclass(softdiff.SceneError, ValueError) and softdiff.SceneError.exit_code == 2
    assert issubclass(softdiff.StepError, RuntimeError) and softdiff.StepError.exit_code == 1
    assert issubclass(softdiff.ConvergenceWarning, RuntimeWarning)
    assert issubclass(softdiff.SceneWarning, UserWarning)
    # Built for Debian's python3 (the tests run under it).
    assert sys.executable == "/usr/bin/python3" or os.path.realpath(sys.executable).startswith("/usr/bin/python3")


def test_thread_plan_reports_the_blas_the_cli_uses():
    plan = softdiff.thread_plan()
    assert set(plan) == {"threads", "blas_threads", "openblas", "blas"}
    # softdiff was imported before numpy (conftest.py): the module's RPATH pins OpenBLAS.
    assert plan["openblas"] and plan["blas"].startswith("OpenBLAS"), plan


# --- load_scene -----------------------------------------------------------------------

def test_load_scene_reads_the_scene():
    scene = softdiff.load_scene(BEAM)
    assert isinstance(scene, softdiff.Scene)
    assert scene.name == "cantilever beam"
    assert scene.path == str(BEAM) and scene.overrides == []
    assert "young: 1.0e6" in scene.text
    assert "cantilever beam" in repr(scene)


def test_overrides_are_the_clis_set_strings():
    scene = softdiff.load_scene(BEAM, overrides={"bodies.beam.material.young": 9.0e5, "simulation.steps": 4,
                                                 "simulation.gravity": [0, 0, -1.5], "bodies.beam.mass": "consistent",
                                                 "output.every": np.int64(2), "simulation.dt": np.float64(0.005)})
    assert scene.overrides == ["bodies.beam.material.young=900000.0", "simulation.steps=4",
                               "simulation.gravity=[0, 0, -1.5]", "bodies.beam.mass=consistent", "output.every=2",
                               "simulation.dt=0.005"]
    sim = softdiff.Simulator(scene)
    assert sim.scene_steps == 4 and sim.dt == 0.005
    # The list-of-strings form is the same scene.
    same = softdiff.load_scene(BEAM, overrides=scene.overrides)
    np.testing.assert_array_equal(softdiff.Simulator(same).run(2)["beam"], sim.run(2)["beam"])


def test_overrides_change_the_motion():
    # A stiffer beam sags less: the young override reaches the model.
    soft = softdiff.Simulator(beam(**{"bodies.beam.material.young": 5.0e5})).run(5)["beam"]
    stiff = softdiff.Simulator(beam(**{"bodies.beam.material.young": 2.0e6})).run(5)["beam"]
    assert soft[-1, :, 2].min() < stiff[-1, :, 2].min() < soft[0, :, 2].min()


def test_override_none_restores_the_default():
    # --set KEY=null: back to the default (gravity 0, 0, -9.81 is the scene's own value).
    scene = softdiff.load_scene(BEAM, overrides={"simulation.gravity": None})
    assert scene.overrides == ["simulation.gravity=null"]


def test_bad_override_values_raise():
    with pytest.raises(TypeError, match="override value"):
        softdiff.load_scene(BEAM, overrides={"simulation.dt": object()})
    with pytest.raises(TypeError, match="KEY.PATH"):
        softdiff.load_scene(BEAM, overrides={3: 1.0})
    with pytest.raises(TypeError, match="a dict"):
        softdiff.load_scene(BEAM, overrides="simulation.dt=0.1")
    with pytest.raises(softdiff.SceneError, match="not a finite number"):
        softdiff.load_scene(BEAM, overrides={"simulation.dt": float("nan")})


# --- SceneError: the CLI's messages ---------------------------------------------------

def test_scene_error_has_file_line_col(tmp_path, cli):
    text = BEAM.read_text().replace("poisson: 0.45", "poisson: 0.7").replace("../meshes/", str(ROOT / "meshes") + "/")
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    line = 1 + text.splitlines().index("      poisson: 0.7")
    with pytest.raises(softdiff.SceneError) as info:
        softdiff.load_scene(path)
    message = str(info.value)
    assert message.startswith(f"{path}:{line}:7: bodies[0].material.poisson: must be in [0, 0.5)"), message
    assert info.value.exit_code == 2
    # The CLI's message, word for word, and its exit code 2.
    r = cli(["simulate", path, "-o", tmp_path / "o.h5"], tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip() == f"softdiff: error: {message}"


def test_scene_error_on_yaml_syntax_and_missing_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("softdiff: 1\nname: x\nbodies: [\n")
    with pytest.raises(softdiff.SceneError, match=rf"^{path}:\d+:\d+: "):
        softdiff.load_scene(path)
    with pytest.raises(softdiff.SceneError, match="nothere.yaml"):
        softdiff.load_scene(tmp_path / "nothere.yaml")


def test_scene_error_on_a_bad_set_key():
    with pytest.raises(softdiff.SceneError, match=r"^--set simulation.dtt: unknown key 'dtt'; did you mean 'dt'\?"):
        softdiff.load_scene(BEAM, overrides={"simulation.dtt": 0.1})
    with pytest.raises(softdiff.SceneError, match=r"^--set: bodies\[0\].material.poisson: must be in"):
        softdiff.load_scene(BEAM, overrides={"bodies.beam.material.poisson": 0.5})


def test_scene_error_from_the_model_build(tmp_path):
    # A physical group the mesh lacks is found when the model is built (Simulator).
    text = BEAM.read_text().replace("group: clamp", "group: clampp").replace("../meshes/", str(ROOT / "meshes") + "/")
    path = tmp_path / "group.yaml"
    path.write_text(text)
    scene = softdiff.load_scene(path)
    line = 1 + text.splitlines().index("      - group: clampp            # the face x = 0")
    with pytest.raises(softdiff.SceneError, match=rf"^{path}:{line}:\d+: bodies\[0\].fixed\[0\].group: .*clampp"):
        softdiff.Simulator(scene)


# --- Simulator: run, step, x, v ------------------------------------------------------

def test_run_shapes_dtypes_and_frames():
    sim = softdiff.Simulator(beam())
    x0 = sim.x("beam")
    assert sim.bodies == ["beam"] and sim.threads == 1 and sim.time == 0.0 and sim.steps_done == 0
    traj = sim.run(4)
    assert list(traj) == ["beam"]
    x = traj["beam"]
    assert x.shape == (5, 1025, 3) and x.dtype == np.float64 and x.flags.c_contiguous and x.flags.writeable
    np.testing.assert_array_equal(x[0], x0)            # frame 0: the state before the run
    np.testing.assert_array_equal(x[-1], sim.x("beam"))  # the last frame: the state now
    assert sim.steps_done == 4 and sim.time == pytest.approx(4 * 0.01, rel=1e-15)
    assert x[-1, :, 2].min() < x[0, :, 2].min()          # it sags
    # run() continues from the state: frame 0 of the next run is the last frame of this one.
    np.testing.assert_array_equal(sim.run(1)["beam"][0], x[-1])
    assert sim.run(0)["beam"].shape == (1, 1025, 3)
    with pytest.raises(ValueError, match="steps must be >= 0"):
        sim.run(-1)


def test_step_is_run_one_step_at_a_time():
    a = softdiff.Simulator(beam())
    b = softdiff.Simulator(beam())
    traj = a.run(3)["beam"]
    for k in range(1, 4):
        b.step()
        assert b.steps_done == k
        np.testing.assert_array_equal(b.x("beam"), traj[k])
    np.testing.assert_array_equal(b.v("beam"), a.v("beam"))
    assert a.time == b.time


def test_x_and_v_are_copies():
    sim = softdiff.Simulator(beam())
    sim.step()
    x, v = sim.x("beam"), sim.v("beam")
    assert x.shape == v.shape == (1025, 3) and x.dtype == v.dtype == np.float64
    keep = x.copy()
    x[:] = 0.0
    v[:] = 0.0
    np.testing.assert_array_equal(sim.x("beam"), keep)
    assert np.abs(sim.v("beam")).max() > 0
    traj = sim.run(1)
    traj["beam"][:] = 0.0   # run()'s arrays are the caller's: the state is untouched
    assert np.abs(sim.x("beam")).max() > 0


def test_unknown_body_raises_key_error():
    sim = softdiff.Simulator(beam())
    with pytest.raises(KeyError, match=r"no body 'arm' in the scene \(bodies: beam\)"):
        sim.x("arm")
    with pytest.raises(KeyError):
        sim.v("arm")


def test_threads():
    softdiff.Simulator(beam(), threads=2)
    assert softdiff.thread_plan()["threads"] == 2
    sim = softdiff.Simulator(beam(), threads=0)   # 0: all cores (OMP_NUM_THREADS), as the CLI's default
    assert sim.threads == 0 and softdiff.thread_plan()["threads"] >= 1
    with pytest.raises(ValueError, match="threads must be >= 0"):
        softdiff.Simulator(beam(), threads=-1)
    # The plan is process-wide: each simulator sets its own again before it steps.
    one, two = softdiff.Simulator(beam(), threads=1), softdiff.Simulator(beam(), threads=2)
    one.step()
    assert softdiff.thread_plan()["threads"] == 1
    two.step()
    assert softdiff.thread_plan()["threads"] == 2
    one.step()
    assert softdiff.thread_plan()["threads"] == 1


def test_static_scene_is_the_clis_bit_for_bit(tmp_path, cli):
    # integrator: static, 4 load steps: run() solves the equilibrium, a frame per load step.
    r = cli(["simulate", STATIC, "-o", tmp_path / "st.h5", "--threads", 1, "--quiet", "--jacobian", "young"], tmp_path)
    assert r.returncode == 0, r.stderr
    sim = softdiff.Simulator(softdiff.load_scene(STATIC), jacobian="young")
    traj = sim.run()
    assert traj["beam"].shape == (5, 1025, 3) and sim.steps_done == 4 and sim.time == 1.0   # the load factor
    np.testing.assert_array_equal(sim.x("beam"), traj["beam"][-1])
    with h5py.File(tmp_path / "st.h5", "r") as f:
        assert np.array_equal(traj["beam"], f["/bodies/beam/x"][...])
        assert np.array_equal(sim.jacobian()["young"], f["/jacobians/young"][...])


def test_static_jacobian_matches_central_differences():
    # d x* / d young at the equilibrium (the implicit function theorem) against central
    # differences of two equilibria. The scene's own convergence test (convergence:
    # answer) leaves a bias of ~5e-7 of the derivative in both equilibria; solved here to
    # a residual of 1e-13 (one load step: the same unique equilibrium, faster) the error
    # is truncation: measured 8.5e-9 at h = 1e-4 E, 1.2e-10 at h = 1e-5 E (used).
    # Tolerance 1e-8 of the largest entry.
    tight = {"simulation.static.convergence": "residual", "simulation.static.tolerance": 1e-13,
             "simulation.static.load_steps": 1}
    E = 1.0e6
    sim = softdiff.Simulator(softdiff.load_scene(STATIC, overrides=tight), jacobian="young")
    sim.run()
    J = sim.jacobian()["young"][:, 0]

    def equilibrium(young):
        s = softdiff.Simulator(softdiff.load_scene(STATIC, overrides={**tight, "bodies.beam.material.young": young}))
        s.run()
        return s.x("beam").reshape(-1)

    h = 1e-5 * E
    fd = (equilibrium(E + h) - equilibrium(E - h)) / (2 * h)
    assert np.abs(fd - J).max() <= 1e-8 * np.abs(J).max()


def test_static_scene_refusals():
    sim = softdiff.Simulator(softdiff.load_scene(STATIC), jacobian="young")
    with pytest.raises(ValueError, match=r"run\(\) solves the static equilibrium first"):
        sim.jacobian()
    with pytest.raises(ValueError, match=r"solved whole: run\(\) solves its equilibrium in its 4 load steps"):
        sim.step()
    with pytest.raises(ValueError, match=r"in its 4 load steps \(static.load_steps\): run\(\) or run\(4\)"):
        sim.run(3)
    with pytest.raises(ValueError, match=r"adjoint\(\) of a static scene takes no steps"):
        sim.adjoint(1)
    sim.run(4)
    with pytest.raises(ValueError, match="solved already"):
        sim.run()
    with pytest.raises(ValueError, match="no velocities"):
        sim.jacobian(of="v")
    with pytest.raises(softdiff.SceneError, match=r"a static scene \(integrator: static\) has no time step"):
        sim.step_jvp()
    with pytest.raises(softdiff.SceneError, match="^jacobian: 'x0' has no effect on a static equilibrium"):
        softdiff.Simulator(softdiff.load_scene(STATIC), jacobian="x0")
    with pytest.raises(ValueError, match="the number of steps is needed"):
        softdiff.Simulator(beam()).run()


def test_rigid_bodies():
    sim = softdiff.Simulator(softdiff.load_scene(STACK))
    assert sim.bodies == ["base", "middle", "top"]
    traj = sim.run(5)
    for name in sim.bodies:
        q = traj[name]
        assert q.shape == (6, 7) and q.dtype == np.float64
        np.testing.assert_allclose(np.linalg.norm(q[:, 3:], axis=1), 1.0, rtol=0, atol=1e-14)  # unit quaternions
        np.testing.assert_array_equal(sim.x(name), q[-1])
        assert sim.v(name).shape == (6,)
    # The top box falls freely for its first steps (1 mm above the middle one):
    # v_z = -g t after implicit Euler's steps, exactly up to round-off.
    assert sim.v("top")[2] == pytest.approx(-9.81 * 5 * 0.002, rel=1e-12)


# --- the CLI's trajectory, bit for bit -------------------------------------------------

@pytest.mark.parametrize("threads", [1, 2])
def test_same_trajectory_as_the_cli(tmp_path, cli, threads):
    steps = 10
    r = cli(["simulate", BEAM, "-o", tmp_path / "beam.h5", "--steps", steps, "--threads", threads, "--quiet"], tmp_path)
    assert r.returncode == 0, r.stderr
    sim = softdiff.Simulator(beam(**{"simulation.steps": steps}), threads=threads)
    traj = sim.run(steps)
    with h5py.File(tmp_path / "beam.h5", "r") as f:
        x = f["/bodies/beam/x"][...]
        v = f["/bodies/beam/v"][...]
        t = f["/time"][...]
    assert x.shape == traj["beam"].shape
    assert np.array_equal(x, traj["beam"])           # bit for bit
    assert np.array_equal(v[-1], sim.v("beam"))
    assert t[-1] == sim.time


def test_same_rigid_trajectory_as_the_cli(tmp_path, cli):
    # 20 steps: 8 contacts from the first step on (the base's corners on the floor, the
    # middle box's within the detection margin of the base), 12 from step 8 on.
    # output.every: 1 (the scene writes every 5th frame; run() returns every step).
    steps = 20
    r = cli(["simulate", STACK, "-o", tmp_path / "stack.h5", "--steps", steps, "--set", "output.every=1", "--threads", 1,
             "--quiet"], tmp_path)
    assert r.returncode == 0, r.stderr
    sim = softdiff.Simulator(softdiff.load_scene(STACK, overrides={"simulation.steps": steps}))
    traj = sim.run(steps)
    with h5py.File(tmp_path / "stack.h5", "r") as f:
        offsets = f["/contact/offsets"][...]
        assert offsets[-1] > offsets[-10] > 0   # the run had contacts, more at the end
        for name in sim.bodies:
            pose = np.concatenate([f[f"/bodies/{name}/position"][...], f[f"/bodies/{name}/orientation"][...]], axis=1)
            assert np.array_equal(pose, traj[name]), name
            vel = np.concatenate([f[f"/bodies/{name}/velocity"][-1], f[f"/bodies/{name}/angular_velocity"][-1]])
            assert np.array_equal(vel, sim.v(name)), name


# --- StepError, warnings ---------------------------------------------------------------

def test_step_error_on_a_diverging_scene(tmp_path, cli):
    sim = softdiff.Simulator(beam(**DIVERGING))
    x0 = sim.x("beam")
    with pytest.raises(softdiff.StepError) as info:
        sim.run(10)
    e = info.value
    assert str(e).startswith("step 1: inverted element: "), str(e)
    assert e.exit_code == 1 and e.steps_done == 0 and e.time == 0.0
    assert list(e.trajectory) == ["beam"] and e.trajectory["beam"].shape == (1, 1025, 3)   # frame 0
    np.testing.assert_array_equal(e.trajectory["beam"][0], x0)
    # The state stays at the last completed step.
    assert sim.steps_done == 0
    np.testing.assert_array_equal(sim.x("beam"), x0)
    with pytest.raises(softdiff.StepError, match="^step 1: inverted element"):
        sim.step()
    # The CLI's message word for word, and its exit code 1.
    args = ["simulate", BEAM, "-o", tmp_path / "d.h5", "--quiet"]
    for key, value in DIVERGING.items():
        args += ["--set", f"{key}={value}"]
    r = cli(args, tmp_path)
    assert r.returncode == 1
    assert r.stderr.splitlines()[0] == f"softdiff: error: {e}"


NOT_CONVERGING = {"simulation.newton_iterations": 2, "simulation.newton_tolerance": 1e-30}


def test_newton_not_converged_warns_or_fails_with_strict():
    sim = softdiff.Simulator(beam(**NOT_CONVERGING))
    with pytest.warns(softdiff.ConvergenceWarning, match=r"^step 1: Newton did not converge in 2 iterations"):
        sim.step()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", softdiff.ConvergenceWarning)
        sim.run(2)
    assert sim.newton_not_converged_steps == 3
    strict = softdiff.Simulator(beam(**NOT_CONVERGING), strict=True)
    with pytest.raises(softdiff.StepError, match=r"^step 1: Newton did not converge in 2 iterations"):
        strict.step()
    # A warnings filter "error" turns the warning into an exception (after the step).
    sim = softdiff.Simulator(beam(**NOT_CONVERGING))
    with warnings.catch_warnings():
        warnings.simplefilter("error", softdiff.ConvergenceWarning)
        with pytest.raises(softdiff.ConvergenceWarning):
            sim.step()


# --- the GIL -------------------------------------------------------------------------

def test_the_gil_is_released_during_steps():
    # A second Python thread runs while run() computes: without the GIL released it
    # could not execute a bytecode between run()'s start and end (the extension never
    # yields it); we count its ticks in the middle half of the run.
    sim = softdiff.Simulator(beam(**{"simulation.steps": 40}))
    span = {}

    def work():
        span["start"] = time.perf_counter()
        sim.run(40)
        span["end"] = time.perf_counter()

    ticks = []
    t = threading.Thread(target=work)
    t.start()
    while t.is_alive():
        ticks.append(time.perf_counter())
        time.sleep(0.001)
    t.join()
    length = span["end"] - span["start"]
    middle = [s for s in ticks if span["start"] + 0.25 * length < s < span["end"] - 0.25 * length]
    assert length > 0.1, "the run is too short to tell"
    assert len(middle) >= 10, (len(middle), length)
    assert sim.steps_done == 40


# --- install -------------------------------------------------------------------------

def test_install_puts_it_where_debian_python_finds_it(tmp_path):
    build = pathlib.Path(softdiff.__file__).resolve().parents[2]   # build/python/softdiff/__init__.py
    stage = tmp_path / "stage"
    r = subprocess.run(["cmake", "--install", str(build), "--component", "python", "--prefix", "/usr/local"],
                       env=dict(os.environ, DESTDIR=str(stage)), capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    site = f"/usr/local/lib/python{sys.version_info[0]}.{sys.version_info[1]}/dist-packages"
    assert (stage / site.lstrip("/") / "softdiff" / "__init__.py").exists()
    # That folder is on Debian python3's path without PYTHONPATH.
    r = subprocess.run(["/usr/bin/python3", "-c", "import sys; print('\\n'.join(sys.path))"],
                       env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"}, capture_output=True, text=True)
    assert site in r.stdout.splitlines(), r.stdout
    # The installed copy imports and runs.
    code = f"import softdiff; print(softdiff.__file__); print(softdiff.Simulator(softdiff.load_scene({str(BEAM)!r})).run(1)['beam'].shape)"
    r = subprocess.run(["/usr/bin/python3", "-c", code], env=dict(os.environ, PYTHONPATH=str(stage / site.lstrip("/"))),
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == [str(stage / site.lstrip("/") / "softdiff" / "__init__.py"), "(2, 1025, 3)"]


def test_implausible_body_warns_or_is_a_scene_error_with_strict():
    # The beam's mesh read as millimetres (mesh_scale 1000): a body of hundreds of metres
    # and tonnes (io/plausibility.hpp), a warning, or with strict bad input (the CLI's --strict).
    scene = beam(**{"bodies.beam.mesh_scale": 1000})
    with pytest.warns(softdiff.SceneWarning, match=r"implausible for a soft robot"):
        softdiff.Simulator(scene)
    with pytest.raises(softdiff.SceneError, match=r"implausible for a soft robot.*--strict") as info:
        softdiff.Simulator(scene, strict=True)
    assert info.value.exit_code == 2


# --- derivatives: forward sensitivities over the --jacobian theta groups -------------------

def test_jacobian_is_the_clis_bit_for_bit(tmp_path, cli):
    steps = 10
    groups = "young,poisson,density,rayleigh_mass"
    r = cli(["simulate", BEAM, "-o", tmp_path / "j.h5", "--steps", steps, "--threads", 1, "--quiet",
             "--jacobian", groups], tmp_path)
    assert r.returncode == 0, r.stderr
    sim = softdiff.Simulator(beam(**{"simulation.steps": steps}), jacobian=groups)
    assert list(sim.theta_columns) == groups.split(",")
    assert sim.theta_columns["young"] == ["young[beam]"]
    sim.run(steps)
    jx, jv = sim.jacobian(), sim.jacobian(of="v")
    with h5py.File(tmp_path / "j.h5", "r") as f:
        for g in groups.split(","):
            J = f[f"/jacobians/{g}"]
            assert J.attrs["theta"] in (g + "[beam]", (g + "[beam]").encode())
            assert jx[g].shape == J.shape == (3 * 1025, 1) and jv[g].shape == J.shape
            assert np.array_equal(jx[g], J[...]), g     # bit for bit
            assert np.abs(jx[g]).max() > 0 and np.abs(jv[g]).max() > 0


def test_rigid_jacobian_is_the_clis_bit_for_bit(tmp_path, cli):
    steps = 10
    r = cli(["simulate", STACK, "-o", tmp_path / "j.h5", "--steps", steps, "--threads", 1, "--quiet",
             "--jacobian", "mass,inertia"], tmp_path)
    assert r.returncode == 0, r.stderr
    sim = softdiff.Simulator(softdiff.load_scene(STACK, overrides={"simulation.steps": steps}), jacobian=["mass", "inertia"])
    sim.run(steps)
    J = sim.jacobian()
    assert J["mass"].shape == (18, 3) and J["inertia"].shape == (18, 18)   # 6 rows per rigid body
    assert sim.rows("middle") == slice(6, 12, 1)
    assert sim.theta_columns["mass"] == ["mass[base]", "mass[middle]", "mass[top]"]
    with h5py.File(tmp_path / "j.h5", "r") as f:
        for g in ("mass", "inertia"):
            assert np.array_equal(J[g], f[f"/jacobians/{g}"][...]), g


def _final_x(overrides, steps):
    sim = softdiff.Simulator(beam(**overrides, **{"simulation.steps": steps}))
    sim.run(steps)
    return sim.x("beam").reshape(-1)


@pytest.mark.parametrize("name, key, value, rel_step", [
    ("young", "bodies.beam.material.young", 1.0e6, 1e-4),
    ("poisson", "bodies.beam.material.poisson", 0.45, 1e-5),   # see below
    ("density", "bodies.beam.material.density", 1070.0, 1e-4),
])
def test_jacobian_matches_central_differences(name, key, value, rel_step):
    # d x_T / d theta over 5 steps against (x_T(theta + h) - x_T(theta - h)) / 2h.
    # The truncation error is O(h^2) relative (the motion is smooth in each parameter:
    # no contact, linearized steps), the round-off floor (the solves' and the positions'
    # rounding over 2h) about 3e-8 of the derivative here. Measured (max error / max
    # entry) at h = 1e-3, 1e-4, 1e-5 theta: young 2.0e-7, 3.2e-8, 3.8e-8; density 7.6e-7,
    # 2.9e-9, 3.2e-7; poisson 5.5e-5, 5.6e-7, 8.0e-9 (its curvature grows as nu nears
    # 0.5, the truncation as (h / (0.5 - nu))^2: h = 1e-5 nu for it, 1e-4 theta for the
    # others). Tolerance 1e-6 of the largest entry: above the errors at those steps (by
    # 30x and more), far below the O(1) error a wrong or missing term would give.
    steps = 5
    sim = softdiff.Simulator(beam(**{"simulation.steps": steps}), jacobian=name)
    sim.run(steps)
    J = sim.jacobian()[name][:, 0]
    h = rel_step * value
    fd = (_final_x({key: value + h}, steps) - _final_x({key: value - h}, steps)) / (2 * h)
    scale = np.abs(J).max()
    assert scale > 0
    err = np.abs(fd - J).max() / scale
    assert err < 1e-6, (name, err)


def test_jacobian_errors():
    with pytest.raises(softdiff.SceneError, match=r"^jacobian young,frobnicate: unknown name 'frobnicate'"):
        softdiff.Simulator(beam(), jacobian="young,frobnicate")
    with pytest.raises(softdiff.SceneError, match=r"^jacobian: 'actuation' needs actuators"):
        softdiff.Simulator(beam(), jacobian=["actuation"])
    with pytest.raises(softdiff.SceneError, match=r"^jacobian: expected a comma-separated list"):
        softdiff.Simulator(beam(), jacobian=[])
    with pytest.raises(TypeError, match="names as strings"):
        softdiff.Simulator(beam(), jacobian=[1])
    sim = softdiff.Simulator(beam())
    assert sim.theta_columns == {}
    with pytest.raises(ValueError, match="no theta"):
        sim.jacobian()
    sim = softdiff.Simulator(beam(), jacobian="young")
    with pytest.raises(ValueError, match="of: 'x' or 'v'"):
        sim.jacobian(of="a")
    # At frame 0 the state does not depend on the parameters yet.
    assert np.array_equal(sim.jacobian()["young"], np.zeros((3 * 1025, 1)))
    assert sim.rows("beam") == slice(0, 3 * 1025, 1)


# --- derivatives: the step's JVP and VJP ----------------------------------------------

def test_step_jvp_matches_central_differences_of_one_step():
    # Step 1 from the initial state (which does not depend on young): dx_1/dE by the JVP
    # with dtheta young = 1 against (x_1(E + h) - x_1(E - h)) / 2h, h = 1e-4 E. One step
    # moves the beam less than five, so the round-off floor is higher relative to the
    # difference: measured 4.0e-7, 1.3e-7, 3.1e-7 of the largest entry at h = 1e-3,
    # 1e-4, 1e-5 E. Tolerance 1e-6 (as test_jacobian_matches_central_differences).
    E = 1.0e6
    sim = softdiff.Simulator(beam(), jacobian="young,poisson")
    sim.step()
    dx, dv = sim.step_jvp(dtheta={"young": 1.0})
    assert dx.shape == dv.shape == (3 * 1025,)
    h = 1e-4 * E
    fd = (_final_x({"bodies.beam.material.young": E + h}, 1) - _final_x({"bodies.beam.material.young": E - h}, 1)) / (2 * h)
    assert np.abs(fd - dx).max() / np.abs(dx).max() < 1e-6
    # Implicit Euler: dx_1 = dx_0 + h dv_1 with dx_0 = 0.
    np.testing.assert_allclose(dx, 0.01 * dv, rtol=0, atol=1e-15 * np.abs(dx).max())
    # It is the first column of the forward sensitivities (the same JVP, computed apart).
    np.testing.assert_allclose(dx, sim.jacobian()["young"][:, 0], rtol=0, atol=1e-12 * np.abs(dx).max())


def test_step_jvp_chains_into_the_forward_sensitivities():
    # dx_k/dE = JVP of step k applied to (dx_{k-1}/dE, dv_{k-1}/dE, dE = 1): the step's
    # JVP in its state directions, checked against the library's forward sensitivities
    # (themselves checked by central differences above). Same solves in another order
    # of operations: agreement to round-off, 1e-10 of the largest entry.
    sim = softdiff.Simulator(beam(), jacobian="young")
    sim.run(3)
    jx, jv = sim.jacobian()["young"][:, 0].copy(), sim.jacobian(of="v")["young"][:, 0].copy()
    sim.step()
    dx, dv = sim.step_jvp(dx=jx, dv=jv, dtheta={"young": 1.0})
    scale = np.abs(sim.jacobian()["young"]).max()
    assert np.abs(dx - sim.jacobian()["young"][:, 0]).max() < 1e-10 * scale
    assert np.abs(dv - sim.jacobian(of="v")["young"][:, 0]).max() < 1e-10 * np.abs(dv).max()


def test_step_vjp_is_the_transpose_of_the_jvp():
    # <bar, J d> = <J^T bar, d> for random d = (dx, dv, dtheta) and bar = (bar_x, bar_v),
    # at step 4 (moving state). Both sides sum ~1e4 products of O(1) random numbers with
    # entries of the step's Jacobian; round-off ~1e-12 relative of the largest term
    # (measured 1.7e-13); tolerance 1e-9 relative.
    rng = np.random.default_rng(7)
    sim = softdiff.Simulator(beam(**{"bodies.beam.material.poisson": 0.3}), jacobian="young,poisson,density,rayleigh_mass")
    sim.run(4)
    n3 = 3 * 1025
    dx, dv = rng.standard_normal(n3) * 1e-3, rng.standard_normal(n3) * 1e-2
    dtheta = {"young": 1e3, "poisson": 1e-3, "density": 1.0, "rayleigh_mass": 1e-2}
    bar_x, bar_v = rng.standard_normal(n3), rng.standard_normal(n3)
    ox, ov = sim.step_jvp(dx=dx, dv=dv, dtheta=dtheta)
    back = sim.step_vjp(bar_x=bar_x, bar_v=bar_v)
    assert set(back) == {"x", "v", "x_prev", "v_prev", "young", "poisson", "density", "rayleigh_mass"}
    lhs = bar_x @ ox + bar_v @ ov
    terms = [back["x"] @ dx, back["v"] @ dv] + [back[g][0] * dtheta[g] for g in dtheta]
    rhs = sum(terms)
    assert abs(lhs - rhs) <= 1e-9 * max(abs(t) for t in terms), (lhs, rhs)


def test_step_derivative_refusals():
    sim = softdiff.Simulator(beam())
    sim.step()
    with pytest.raises(ValueError, match="no theta"):
        sim.step_jvp()
    sim = softdiff.Simulator(beam(), jacobian="young")
    with pytest.raises(ValueError, match="no step to differentiate"):
        sim.step_vjp()
    sim.step()
    with pytest.raises(ValueError, match="3075 values expected, got 3"):
        sim.step_jvp(dx=[1.0, 2.0, 3.0])
    with pytest.raises(KeyError, match="not one of the simulator's theta groups"):
        sim.step_jvp(dtheta={"poisson": 1.0})
    # (Rigid bodies and BDF2: tests/python/test_state_and_step_derivatives.py.)
    # After a failed step there is no record to differentiate.
    bad = softdiff.Simulator(beam(**DIVERGING), jacobian="young")
    with pytest.raises(softdiff.StepError):
        bad.step()
    with pytest.raises(ValueError, match="no step to differentiate"):
        bad.step_jvp()


# --- derivatives: the adjoint ---------------------------------------------------------

def test_adjoint_is_the_forward_sensitivities_transposed():
    # l = w . x_T + u . v_T over 5 steps: the adjoint's dl/dtheta equals w . dx_T/dtheta +
    # u . dv_T/dtheta from the forward sensitivities (both FD-checked above), to round-off
    # of the two orders of summation (measured 6.6e-13 and 3.7e-13 relative; asserted 1e-10).
    rng = np.random.default_rng(3)
    w, u = rng.standard_normal(3 * 1025), rng.standard_normal(3 * 1025)
    sim = softdiff.Simulator(beam(), jacobian="young,poisson")
    g = sim.adjoint(5, bar_x=w, bar_v=u)
    assert set(g) == {"young", "poisson", "x", "v", "rigid", "x_T", "v_T", "recompute_mismatch"}
    assert g["recompute_mismatch"] == 0.0          # the reverse sweep recomputed the run bit for bit
    assert sim.steps_done == 0 and sim.time == 0.0   # the simulator did not move
    assert g["x"].shape == g["v"].shape == (3 * 1025,) and g["rigid"].shape == (0,)
    sim.run(5)
    assert np.array_equal(g["x_T"], sim.x("beam").reshape(-1))   # the same run as the simulator's
    for k in ("young", "poisson"):
        f = w @ sim.jacobian()[k][:, 0] + u @ sim.jacobian(of="v")[k][:, 0]
        assert g[k].shape == (1,)
        assert abs(g[k][0] - f) <= 1e-10 * abs(f), (k, g[k][0], f)
    # theta= chooses other groups for one call.
    assert set(sim.adjoint(1, bar_x=w, theta=["density"])) >= {"density"}


def test_adjoint_with_rigid_bodies():
    # The rigid stack over 10 steps (contact): dl/dx0, dl/dv0 of the rigid states by the
    # adjoint against the forward sensitivities; measured 7.5e-15 and 2.1e-15 of the
    # largest entry, asserted 1e-11.
    rng = np.random.default_rng(5)
    w, u = rng.standard_normal(18), rng.standard_normal(18)
    bar_rigid = np.concatenate([np.concatenate([w[6 * r:6 * r + 6], u[6 * r:6 * r + 6]]) for r in range(3)])
    sim = softdiff.Simulator(softdiff.load_scene(STACK), jacobian="x0,v0")
    g = sim.adjoint(10, bar_rigid=bar_rigid)
    assert g["recompute_mismatch"] == 0.0 and g["rigid"].shape == (36,) and g["x"].shape == (0,)
    sim.run(10)
    for k in ("x0", "v0"):
        f = w @ sim.jacobian()[k] + u @ sim.jacobian(of="v")[k]
        assert np.abs(g[k] - f).max() <= 1e-11 * np.abs(f).max(), k
    # The current state's rigid cotangent is theta's x0, v0 columns body by body.
    assert np.array_equal(g["rigid"], np.concatenate([np.concatenate([g["x0"][6 * r:6 * r + 6],
                                                                      g["v0"][6 * r:6 * r + 6]]) for r in range(3)]))


def test_adjoint_errors():
    sim = softdiff.Simulator(beam())
    with pytest.raises(ValueError, match="no theta"):
        sim.adjoint(2)
    with pytest.raises(softdiff.SceneError, match=r"^theta frobnicate: unknown name 'frobnicate'"):
        sim.adjoint(2, theta="frobnicate")
    with pytest.raises(ValueError, match="bar_x: 3075 values expected, got 2"):
        sim.adjoint(2, bar_x=[1.0, 2.0], theta="young")
    with pytest.raises(ValueError, match="steps must be >= 0"):
        sim.adjoint(-1, theta="young")
    bad = softdiff.Simulator(beam(**DIVERGING))
    with pytest.raises(softdiff.StepError, match="^step 1: inverted element") as info:
        bad.adjoint(3, theta="young")
    assert info.value.exit_code == 1


# --- reading a softdiff HDF5 -------------------------------------------------------------

def test_read_result_reads_the_clis_output(tmp_path, cli):
    r = cli(["simulate", BEAM, "-o", tmp_path / "b.h5", "--steps", 3, "--threads", 1, "--quiet", "--jacobian", "young"],
            tmp_path)
    assert r.returncode == 0, r.stderr
    res = softdiff.read_result(tmp_path / "b.h5")
    assert res.status == "complete" and res.attributes["softdiff_format"] == 1
    assert "xdmf" not in res.data and "4 frames" in repr(res)   # 3 steps: frames 0-3
    with h5py.File(tmp_path / "b.h5", "r") as f:
        np.testing.assert_array_equal(res.time, f["/time"][...])
        for name in ("x", "v", "rest", "displacement"):
            a = res.bodies["beam"][name]
            assert a.dtype == np.float64 and np.array_equal(a, f[f"/bodies/beam/{name}"][...]), name
        for name in ("tets", "surface"):
            a = res.bodies["beam"][name]
            assert a.dtype == np.int64 and np.array_equal(a, f[f"/bodies/beam/{name}"][...]), name
        assert np.array_equal(res.jacobians["young"], f["/jacobians/young"][...])
    # The Python run's trajectory is the file's.
    sim = softdiff.Simulator(beam())
    assert np.array_equal(sim.run(3)["beam"], res.bodies["beam"]["x"])


def test_read_result_rigid_contact_and_diverged(tmp_path, cli):
    r = cli(["simulate", STACK, "-o", tmp_path / "s.h5", "--steps", 5, "--threads", 1, "--quiet"], tmp_path)
    assert r.returncode == 0, r.stderr
    res = softdiff.read_result(tmp_path / "s.h5")
    assert res.bodies["top"]["orientation"].shape == (2, 4)   # output.every 5: frames 0 and 5
    assert res.data["contact"]["offsets"].dtype == np.int64
    assert res.data["contact"]["force"].shape[1] == 3
    args = ["simulate", BEAM, "-o", tmp_path / "d.h5", "--quiet"]
    for key, value in DIVERGING.items():
        args += ["--set", f"{key}={value}"]
    assert cli(args, tmp_path).returncode == 1
    res = softdiff.read_result(tmp_path / "d.h5")
    assert res.status.startswith("diverged: step 1: inverted element")
    assert res.bodies["beam"]["x"].shape == (1, 1025, 3)


def test_read_result_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such file"):
        softdiff.read_result(tmp_path / "none.h5")
    (tmp_path / "text.h5").write_text("not hdf5")
    with pytest.raises(ValueError, match=r"not a softdiff HDF5 output \(not an HDF5 file\)"):
        softdiff.read_result(tmp_path / "text.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["a"] = np.zeros(3)
    with pytest.raises(ValueError, match="no root attribute 'status'"):
        softdiff.read_result(tmp_path / "other.h5")
