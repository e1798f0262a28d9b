"""Output files from Python (docs/python.md "Output files"): softdiff.calibrate(output=),
softdiff.control(output=) and softdiff.simulate() write the CLI's file, through the
same library run (io/run_output.hpp). Compared with the CLI's file dataset by dataset
(h5py): every dataset equal, bit for bit, but the timing ones (/solver/step_seconds),
and every attribute but the file's `command` and the timings. Small runs (~15 s in all)."""
import os
import pathlib

import numpy as np
import pytest

import softdiff

h5py = pytest.importorskip("h5py")

ROOT = pathlib.Path(os.environ.get("SOFTDIFF_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
CALIB = ROOT / "configs" / "calib_beam.yaml"
BEAM = ROOT / "configs" / "beam_cantilever.yaml"
SHORT = {"simulation.duration": 0.1}
# Datasets that measure wall time (never reproducible): whole, or their last column
# (/calibration/iterations: seconds), and root attributes naming the run.
TIMING_DATASETS = {"solver/step_seconds"}
TIMING_LAST_COLUMN = {"calibration/iterations"}
RUN_ATTRIBUTES = {"command", "created", "host", "softdiff_version", "wall_seconds", "setup_seconds"}


def datasets(path):
    """{name: (array, attributes)} of every dataset, and the groups' attributes."""
    out, groups = {}, {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            attrs = {k: v for k, v in obj.attrs.items()}
            if isinstance(obj, h5py.Dataset):
                out[name] = (obj[()], attrs)
            else:
                groups[name] = attrs
        f.visititems(visit)
        groups["/"] = dict(f.attrs.items())
    return out, groups


def assert_same_file(got_path, cli_path):
    got, got_groups = datasets(got_path)
    cli, cli_groups = datasets(cli_path)
    assert sorted(got) == sorted(cli)
    assert sorted(got_groups) == sorted(cli_groups)
    compared = 0
    for name, (value, attrs) in cli.items():
        assert got[name][1].keys() == attrs.keys(), name
        for k, v in attrs.items():
            assert np.array_equal(got[name][1][k], v), (name, k)
        if name in TIMING_DATASETS:
            assert got[name][0].shape == value.shape, name
            continue
        if name in TIMING_LAST_COLUMN:
            assert np.array_equal(got[name][0][:, :-1], value[:, :-1]), name
            compared += 1
            continue
        if value.dtype.kind == "f":
            assert np.array_equal(got[name][0], value, equal_nan=True), name  # bit for bit
        else:
            assert np.array_equal(got[name][0], value), name
        compared += 1
    for group, attrs in cli_groups.items():
        keys = set(attrs) - (RUN_ATTRIBUTES if group == "/" else set())
        assert keys <= set(got_groups[group]), group
        for k in keys:
            assert np.array_equal(got_groups[group][k], attrs[k]), (group, k)
    assert got_groups["/"]["command"].startswith("python: softdiff.")
    return compared


@pytest.fixture(scope="module")
def beam_target(tmp_path_factory):
    d = tmp_path_factory.mktemp("target")
    softdiff.simulate(CALIB, output=d / "target.h5", set=SHORT, threads=1)
    return d / "target.h5"


def test_simulate_writes_the_cli_file_with_its_jacobian(tmp_path, cli):
    r = cli(["simulate", BEAM, "--jacobian", "young", "--steps", "10", "-o", "cli.h5", "--quiet", "--threads", "1"],
            tmp_path)
    assert r.returncode == 0, r.stderr
    got = softdiff.simulate(BEAM, output=tmp_path / "py.h5", steps=10, jacobian=["young"], threads=1)
    assert got["output"] == str(tmp_path / "py.h5") and got["status"] == "complete"
    assert got["steps"] == 10 and got["frames"] == 11 and "derivatives" in got
    assert assert_same_file(tmp_path / "py.h5", tmp_path / "cli.h5") > 5
    with h5py.File(tmp_path / "py.h5", "r") as f:
        assert f["jacobians/young"].shape[1] == 1 and np.abs(f["jacobians/young"][()]).max() > 0


def test_calibrate_output_is_the_cli_file(tmp_path, cli, beam_target):
    r = cli(["calibrate", CALIB, "--param", "young", "--init", "5e5", "--target", beam_target, "-o", "cli.h5",
             "--quiet", "--threads", "1", "--set", "simulation.duration=0.1"], tmp_path)
    assert r.returncode == 0, r.stderr
    got = softdiff.calibrate(CALIB, param="young", init=[5e5], target=beam_target, set=SHORT, threads=1,
                             output=tmp_path / "py.h5")
    assert got["output"] == str(tmp_path / "py.h5") and got["converged"]
    assert assert_same_file(tmp_path / "py.h5", tmp_path / "cli.h5") > 5
    with h5py.File(tmp_path / "py.h5", "r") as f:
        it = f["calibration/iterations"][()]
        assert it.shape == (len(got["history"]), 1 + 5)
        assert f["calibration"].attrs["young"] == got["parameters"]["young"]


def test_control_output_is_the_cli_file(tmp_path, cli, servo_beam_scene):
    scene = servo_beam_scene(tmp_path / "servo.yaml", 20)
    r = cli(["control", scene, "--target=0.2,0.015,0.01", "-o", "cli.h5", "--quiet", "--threads", "1"], tmp_path)
    assert r.returncode == 0, r.stderr
    got = softdiff.control(scene, target=(0.2, 0.015, 0.01), threads=1, output=tmp_path / "py.h5")
    assert got["output"] == str(tmp_path / "py.h5")
    assert assert_same_file(tmp_path / "py.h5", tmp_path / "cli.h5") > 5
    # The result's series are the file's, and those of a run without a file.
    without = softdiff.control(scene, target=(0.2, 0.015, 0.01), threads=1)
    with h5py.File(tmp_path / "py.h5", "r") as f:
        for key in ("goal", "distance", "actuation", "kkt_residual"):
            assert np.array_equal(got[key], f["control"][key][()]), key
            assert np.array_equal(without[key], got[key]), key
        assert np.array_equal(got["time"], f["time"][()])


def test_force_semantics_and_the_refusal_to_overwrite(tmp_path, cli, beam_target):
    out = tmp_path / "out.h5"
    out.write_text("precious\n")
    # The CLI's message for an existing file without --force (exit 2), as SceneError.
    r = cli(["calibrate", CALIB, "--param", "young", "--init", "5e5", "--target", beam_target, "-o", out,
             "--quiet", "--threads", "1", "--set", "simulation.duration=0.1"], tmp_path)
    assert r.returncode == 2
    message = r.stderr.strip().splitlines()[-1].removeprefix("softdiff: error: ")
    with pytest.raises(softdiff.SceneError) as e:
        softdiff.calibrate(CALIB, param="young", init=[5e5], target=beam_target, set=SHORT, threads=1, output=out)
    assert str(e.value) == message and e.value.exit_code == 2
    assert out.read_text() == "precious\n"  # untouched
    r = cli(["simulate", BEAM, "--steps", "2", "-o", out, "--quiet", "--threads", "1"], tmp_path)
    assert r.returncode == 2
    with pytest.raises(softdiff.SceneError) as e:
        softdiff.simulate(BEAM, output=out, steps=2, threads=1)
    assert str(e.value) == r.stderr.strip().splitlines()[-1].removeprefix("softdiff: error: ")
    assert out.read_text() == "precious\n"
    # force=True overwrites it with the run's file.
    got = softdiff.calibrate(CALIB, param="young", init=[5e5], target=beam_target, set=SHORT, threads=1, output=out,
                             force=True)
    assert got["converged"] and softdiff.read_result(out).status == "complete"
    got = softdiff.simulate(BEAM, output=out, steps=2, threads=1, force=True)
    assert got["status"] == "complete" and len(softdiff.read_result(out).time) == 3
    # force= without output=: refused, not ignored.
    with pytest.raises(ValueError, match="force=True: only with output="):
        softdiff.control(BEAM, target=(0, 0, 0), force=True)


def test_bad_output_path_is_a_scene_error_and_leaves_no_file(tmp_path, cli, beam_target, servo_beam_scene):
    scene = servo_beam_scene(tmp_path / "servo.yaml", 20)
    missing = tmp_path / "no_such_folder" / "out.h5"
    for run in (lambda: softdiff.simulate(BEAM, output=missing, steps=2, threads=1),
                lambda: softdiff.control(scene, target=(0.2, 0.015, 0.01), steps=2, threads=1, output=missing),
                lambda: softdiff.calibrate(CALIB, param="young", init=[5e5], target=beam_target, set=SHORT,
                                           max_iterations=1, threads=1, output=missing)):
        with pytest.raises(softdiff.SceneError) as e:
            run()
        assert e.value.exit_code == 2
        assert str(missing.parent) in str(e.value)
        assert not missing.parent.exists()
    # The output may not be an input (the CLI's message): the scene itself.
    r = cli(["control", scene, "--target=0.2,0.015,0.01", "-o", scene, "--quiet"], tmp_path)
    assert r.returncode == 2
    with pytest.raises(softdiff.SceneError) as e:
        softdiff.control(scene, target=(0.2, 0.015, 0.01), output=scene)
    assert str(e.value) == r.stderr.strip().splitlines()[-1].removeprefix("softdiff: error: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["servo.yaml"]


def test_a_failed_run_finishes_the_file_as_the_cli_and_says_where(tmp_path, cli):
    # The control test's failing scene (test_optim.py): a very soft beam, a huge step.
    sets = {"bodies.beam.material.young": 1, "simulation.dt": 0.5, "simulation.gravity": [0, 0, -9.81]}
    r = cli(["simulate", BEAM, "--steps", "2", "-o", "cli.h5", "--quiet", "--threads", "1"]
            + [a for k, v in sets.items() for a in ("--set", f"{k}={v}")], tmp_path)
    assert r.returncode == 1, r.stderr
    cli_lines = [line.removeprefix("softdiff: ").removeprefix("error: ") for line in r.stderr.strip().splitlines()]
    with pytest.raises(softdiff.StepError) as e:
        softdiff.simulate(BEAM, output=tmp_path / "py.h5", steps=2, set=sets, threads=1)
    assert e.value.exit_code == 1
    # The CLI's error line, then its note on where the frames are ("frame 0 is in FILE":
    # a new file is finished under its name, with the status diverged; an existing one
    # overwritten with force=True would be left unchanged and the frames go to a side file).
    assert str(e.value) == "; ".join(cli_lines).replace("cli.h5", str(tmp_path / "py.h5"))
    assert softdiff.read_result(tmp_path / "py.h5").status == softdiff.read_result(tmp_path / "cli.h5").status
    assert softdiff.read_result(tmp_path / "py.h5").status.startswith("diverged: step 1: inverted element")
    assert assert_same_file(tmp_path / "py.h5", tmp_path / "cli.h5") > 5


def test_ctrl_c_stops_after_the_step_and_finishes_the_file_as_interrupted(tmp_path):
    # A Python process writing a long run gets SIGINT (the interpreter's handler: the module
    # installs none) once its file exists: the run stops after the step in progress, the
    # file is finished with status interrupted and KeyboardInterrupt names where the frames are.
    import signal
    import subprocess
    import sys
    import time
    script = (f"import softdiff\n"
              f"try:\n"
              f"    softdiff.simulate({str(BEAM)!r}, output='run.h5', steps=5000, threads=1)\n"
              f"except KeyboardInterrupt as e:\n"
              f"    print('KeyboardInterrupt:', e)\n")
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(pathlib.Path(softdiff.__file__).parents[1]))
    p = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (tmp_path / "run.h5.partial").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # a few steps
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert out.startswith("KeyboardInterrupt: interrupted after "), (out, err)
    assert "are in run.h5" in out
    r = softdiff.read_result(tmp_path / "run.h5")
    assert r.status == "interrupted" and 2 <= len(r.time) < 5001
