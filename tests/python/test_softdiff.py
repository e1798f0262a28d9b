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
    with pytest.raises(KeyError, match="no body 'arm' in the scene \\(bodies: beam\\)"):
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


def test_static_scenes_are_refused_naming_the_issue():
    with pytest.raises(ValueError, match="issue 23"):
        softdiff.Simulator(softdiff.load_scene(STATIC))


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
