"""softdiff.calibrate() and softdiff.control() (docs/python.md "calibrate and control"):
the same results as the CLI's `calibrate --json` and `control --json` (and its /control
series), bit for bit, and the CLI's messages for bad input. Small runs: a 10-step
calibration of the beam and a 40-step control of a servo-driven beam (~10 s in all)."""
import json
import os
import pathlib
import warnings

import numpy as np
import pytest

import softdiff

ROOT = pathlib.Path(os.environ.get("SOFTDIFF_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))
CALIB = ROOT / "configs" / "calib_beam.yaml"  # the paper's beam, 30 steps: 10 here (duration 0.1)
SHORT = {"simulation.duration": 0.1}
# Keys of --json that measure time (not reproducible) or name the CLI's output file.
TIMING = {"wall_seconds", "output", "control_ms_per_step", "other_ms_per_step"}


def cli_error(r):
    """The CLI's message of an exit-2 run: its stderr without the `softdiff: error: ` prefix
    and, for the options its argument parser checks (--max-iterations, --steps), without
    the parser's pointer to the CLI's help, " (see softdiff --help)"."""
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("softdiff: error: "), r.stderr
    return line[len("softdiff: error: "):].removesuffix(" (see softdiff --help)")


@pytest.fixture(scope="module")
def beam_target(tmp_path_factory):
    """The beam's 10-step trajectory with the scene's values (young 1e6): the target."""
    d = tmp_path_factory.mktemp("calib")
    import subprocess
    exe = pathlib.Path(os.environ.get("SOFTDIFF_CLI", ROOT / "build" / "bin" / "softdiff"))
    r = subprocess.run([str(exe), "simulate", str(CALIB), "-o", "target.h5", "--quiet", "--threads", "1",
                        "--set", "simulation.duration=0.1"], cwd=d, capture_output=True, text=True,
                       env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert r.returncode == 0, r.stderr
    return d / "target.h5"


@pytest.fixture
def control_scene(tmp_path, servo_beam_scene):
    return servo_beam_scene(tmp_path / "servo.yaml", 40)


# --- calibrate ------------------------------------------------------------------------

def test_calibrate_equals_the_cli_json_bit_for_bit(tmp_path, cli, beam_target):
    # From half the truth: Levenberg-Marquardt on the exact Jacobian finds young = 1e6.
    r = cli(["calibrate", CALIB, "--param", "young", "--init", "5e5", "--target", beam_target, "-o", "cal.h5",
             "--json", "--quiet", "--threads", "1", "--set", "simulation.duration=0.1"], tmp_path)
    assert r.returncode == 0, r.stderr
    expected = json.loads(r.stdout)
    got = softdiff.calibrate(str(CALIB), param=["young"], init=[5e5], target=beam_target, set=SHORT, threads=1)
    assert got["output"] is None and got["wall_seconds"] > 0
    assert got["converged"] is True and abs(got["parameters"]["young"] / 1e6 - 1) < 1e-6, got["parameters"]
    for key, value in expected.items():
        if key in TIMING:
            continue
        if key == "history":
            assert len(got[key]) == len(value)
            for h_got, h_cli in zip(got[key], value):
                for k, v in h_cli.items():
                    if k != "seconds":
                        assert h_got[k] == v, (key, k, h_got[k], v)  # == on floats: bit for bit
            continue
        assert got[key] == value, (key, got[key], value)
    assert set(got) - set(expected) == {"notes"}
    # The scene as a Scene object: its overrides are the --set strings.
    again = softdiff.calibrate(softdiff.load_scene(CALIB, overrides=SHORT), param="young", init="5e5",
                               target=str(beam_target), threads=1)
    assert again["parameters"] == got["parameters"] and again["final_cost"] == got["final_cost"]


def test_calibrate_from_markers_equals_the_cli_json(tmp_path, cli, beam_target):
    # Four points of the beam followed in the target (tests/app/test_cli_calibrate.cpp
    # RecoversYoungFromMarkers): the nodes' positions at frames 0, 5 and 10.
    f = softdiff.read_result(beam_target)
    x = f.bodies["beam"]["x"]
    lines = ["time,marker,x,y,z"]
    for k in (0, 5, 10):
        for m, node in enumerate((100, 400, 700, 1000)):
            lines.append(f"{f.time[k]!r},m{m}," + ",".join(repr(float(c)) for c in x[k, node]))
    (tmp_path / "markers.csv").write_text("\n".join(lines) + "\n")
    r = cli(["calibrate", CALIB, "--param", "young", "--init", "5e5", "--markers", "markers.csv", "-o", "cal.h5",
             "--json", "--quiet", "--threads", "1", "--set", "simulation.duration=0.1"], tmp_path)
    assert r.returncode == 0, r.stderr
    expected = json.loads(r.stdout)
    got = softdiff.calibrate(CALIB, param="young", init=[5e5], markers=tmp_path / "markers.csv", set=SHORT, threads=1)
    assert got["residuals"] == 2 * 4 * 3 and got["target_steps"] == 10
    assert abs(got["parameters"]["young"] / 1e6 - 1) < 1e-6
    for key in ("converged", "stop_reason", "iterations", "evaluations", "final_cost", "parameters", "residuals"):
        assert got[key] == expected[key], key
    assert [h["values"] for h in got["history"]] == [h["values"] for h in expected["history"]]


def test_calibrate_frames_and_the_single_frame_warning(beam_target):
    with pytest.warns(softdiff.SceneWarning, match="a single frame as target"):
        r = softdiff.calibrate(CALIB, param="young", init=[5e5], target=beam_target, frames="last", set=SHORT,
                               max_iterations=1)
    assert r["target_steps"] == 10 and r["iterations"] == 1 and not r["converged"]  # the CLI exits 1
    r = softdiff.calibrate(CALIB, param="young", init=[5e5], target=beam_target, frames=[3, 7], set=SHORT,
                           max_iterations=1)
    assert r["target_steps"] == 7 and r["residuals"] == 2 * 3 * 1025


def test_calibrate_bad_input_raises_scene_error_with_the_cli_message(tmp_path, cli, beam_target):
    (tmp_path / "not_hdf5.h5").write_text("x\n")
    (tmp_path / "markers.csv").write_text("time,marker,x,y,z\n0,tip,0.2\n")
    cases = [
        (["--param", "yung", "--target", beam_target], dict(param="yung", target=beam_target)),
        (["--param", "young", "--target", "missing.h5"], dict(param="young", target=tmp_path / "missing.h5")),
        (["--param", "young", "--target", "not_hdf5.h5"], dict(param="young", target=tmp_path / "not_hdf5.h5")),
        (["--param", "young", "--target", beam_target, "--init", "1,2"], dict(param="young", target=beam_target,
                                                                             init=[1, 2])),
        (["--param", "young", "--target", beam_target, "--frames", "11"], dict(param="young", target=beam_target,
                                                                              frames=[11])),
        (["--param", "young"], dict(param="young")),
        (["--param", "young", "--markers", "markers.csv"], dict(param="young", markers=tmp_path / "markers.csv")),
        (["--param", "young", "--target", beam_target, "--max-iterations", "0"],
         dict(param="young", target=beam_target, max_iterations=0)),
    ]
    for args, kwargs in cases:
        r = cli(["calibrate", CALIB, "-o", "never.h5", "--quiet", "--set", "simulation.duration=0.1"] + args, tmp_path)
        message = cli_error(r)
        # Relative paths in the CLI's message: the same file given absolute to Python.
        for name in ("missing.h5", "not_hdf5.h5", "markers.csv"):
            message = message.replace(name, str(tmp_path / name))
        with pytest.raises(softdiff.SceneError) as e:
            softdiff.calibrate(CALIB, set=SHORT, **kwargs)
        assert str(e.value) == message, args
        assert e.value.exit_code == 2
        assert not (tmp_path / "never.h5").exists()
    # --tolerance: the CLI echoes its text ("0"), Python its value ("0.0").
    with pytest.raises(softdiff.SceneError, match=r"^--tolerance: must be > 0, got 0.0$"):
        softdiff.calibrate(CALIB, param="young", target=beam_target, tolerance=0, set=SHORT)
    # force= only with output= (tests/python/test_output.py: output= itself).
    with pytest.raises(ValueError, match="force=True: only with output="):
        softdiff.calibrate(CALIB, param="young", target=beam_target, set=SHORT, force=True)


# --- control --------------------------------------------------------------------------

def test_control_equals_the_cli_json_and_control_series_bit_for_bit(tmp_path, cli, control_scene):
    r = cli(["control", control_scene, "--target=0.2,0.015,0.01", "-o", "c.h5", "--json", "--quiet", "--threads", "1"],
            tmp_path)
    assert r.returncode == 0, r.stderr
    expected = json.loads(r.stdout)
    got = softdiff.control(control_scene, target=(0.2, 0.015, 0.01), threads=1)
    for key, value in expected.items():
        if key not in TIMING:
            assert got[key] == value, (key, got[key], value)
    assert got["steps"] == 40 and got["within_limits"] and got["final_distance"] < 1e-3
    # The /control series of the CLI's file, frame for frame.
    f = softdiff.read_result(tmp_path / "c.h5")
    c = f.data["control"]
    assert np.array_equal(got["time"], f.time)
    for name in ("goal", "distance", "actuation", "kkt_residual"):
        assert np.array_equal(got[name], c[name].reshape(got[name].shape)), name
    assert "contact_force_norm" not in got and "contact_force_norm" not in c


def test_control_timed_goals_and_output_every(tmp_path, cli, control_scene):
    goals = tmp_path / "goals.csv"
    goals.write_text("time,x,y,z\n0,0.2,0.01,0.01\n0.4,0.2,0.015,0.01\n")
    args = ["--weights", "1,0", "--axes", "y", "--filter", "0.5", "--regularization", "1e-4", "--steps", "30",
            "--set", "output.every=4"]
    r = cli(["control", control_scene, "--target", goals, "-o", "c.h5", "--json", "--quiet", "--threads", "1"] + args,
            tmp_path)
    assert r.returncode == 0, r.stderr
    expected = json.loads(r.stdout)
    got = softdiff.control(control_scene, target=goals, weights=(1, 0), axes="y", filter=0.5, regularization=1e-4,
                           steps=30, set={"output.every": 4}, threads=1)
    for key, value in expected.items():
        if key not in TIMING:
            assert got[key] == value, (key, got[key], value)
    f = softdiff.read_result(tmp_path / "c.h5")
    assert len(got["time"]) == len(f.time) == 1 + 7 + 1  # frames 0, 4, ..., 28 and the last, 30
    assert np.array_equal(got["distance"], f.data["control"]["distance"])
    assert np.array_equal(got["goal"], f.data["control"]["goal"])


def test_control_through_contact_with_a_rigid_block_equals_the_cli(tmp_path, cli, control_scene):
    # tests/app/test_cli_control.cpp PushesAFreeRigidBlock: the tip pushes a free rigid
    # block (contact, beta > 0: the contact-force term through the NCP derivative).
    scene = tmp_path / "block.yaml"
    scene.write_text(control_scene.read_text() + """  - name: block
    type: rigid
    shape: {type: box, half_extents: [0.015, 0.005, 0.015]}
    density: 300
    position: [0.19, 0.0255, 0.01]
contact: {friction: 0.3, pairs: [[beam, block, 0.3]]}
""")
    r = cli(["control", scene, "--target", "0.2,0.025,0.01", "--axes", "y", "--weights", "1,1", "-o", "c.h5", "--json",
             "--quiet", "--threads", "1"], tmp_path)
    assert r.returncode == 0, r.stderr
    expected = json.loads(r.stdout)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = softdiff.control(scene, target="0.2,0.025,0.01", axes="y", weights="1,1", threads=1)
    for key, value in expected.items():
        if key not in TIMING:
            assert got[key] == value, (key, got[key], value)
    c = softdiff.read_result(tmp_path / "c.h5").data["control"]
    assert np.array_equal(got["contact_force_norm"], c["contact_force_norm"])
    assert got["contact_force_norm"].max() > 1e-4  # the tip pushed the block
    # The CLI's non-convergence warnings (the first one shown), --strict as strict=True.
    cli_warnings = [line[len("softdiff: warning: "):] for line in r.stderr.splitlines()
                    if line.startswith("softdiff: warning: ")]
    got_warnings = [str(w.message) for w in caught if issubclass(w.category, softdiff.ConvergenceWarning)]
    assert got_warnings == [w.replace("--strict makes it an error", "strict=True makes it an error")
                            for w in cli_warnings]
    assert (got["contact_not_converged_steps"] > 0) == bool(cli_warnings)


def test_control_bad_input_raises_scene_error_with_the_cli_message(tmp_path, cli, control_scene):
    bad = tmp_path / "bad.csv"
    bad.write_text("time,x,y,z\n0,0.2,0.01\n")
    cases = [
        (["--target=0.2,0.015,0.01", "--effector", "nope"], dict(target=(0.2, 0.015, 0.01), effector="nope")),
        (["--target", "bad.csv"], dict(target=bad)),
        (["--target", "missing.csv"], dict(target=tmp_path / "missing.csv")),
        (["--target=0.2,0.015,0.01", "--weights", "1,-1"], dict(target=(0.2, 0.015, 0.01), weights="1,-1")),
        (["--target=0.2,0.015,0.01", "--weights", "1,1"], dict(target=(0.2, 0.015, 0.01), weights=(1, 1))),
        (["--target=0.2,0.015,0.01", "--axes", "xw"], dict(target=(0.2, 0.015, 0.01), axes="xw")),
        (["--target=0.2,0.015,0.01", "--steps", "0"], dict(target=(0.2, 0.015, 0.01), steps=0)),
    ]
    for args, kwargs in cases:
        r = cli(["control", control_scene, "-o", "never.h5", "--quiet"] + args, tmp_path)
        message = cli_error(r).replace("bad.csv", str(bad)).replace("missing.csv", str(tmp_path / "missing.csv"))
        with pytest.raises(softdiff.SceneError) as e:
            softdiff.control(control_scene, **kwargs)
        assert str(e.value) == message, args
        assert not (tmp_path / "never.h5").exists()
    with pytest.raises(softdiff.SceneError, match=r"^--filter 2: must be in \(0, 1\]$"):
        softdiff.control(control_scene, target=(0, 0, 0), filter=2)
    with pytest.raises(ValueError, match="force=True: only with output="):
        softdiff.control(control_scene, target=(0, 0, 0), force=True)


def test_control_step_error_carries_the_cli_message(tmp_path, cli, control_scene):
    # A huge step of a very soft beam under gravity inverts an element in the first step's
    # prediction (the CLI exits 1).
    sets = ["--set", "bodies.beam.material.young=1", "--set", "simulation.dt=0.5", "--set",
            "simulation.gravity=[0, 0, -9.81]", "--steps", "2"]
    r = cli(["control", control_scene, "--target=0.2,0.015,0.01", "-o", "c.h5", "--quiet"] + sets, tmp_path)
    assert r.returncode == 1
    message = r.stderr.strip().splitlines()[0]
    with pytest.raises(softdiff.StepError) as e:
        softdiff.control(control_scene, target=(0.2, 0.015, 0.01), steps=2,
                         set={"bodies.beam.material.young": 1, "simulation.dt": 0.5,
                              "simulation.gravity": [0, 0, -9.81]})
    assert message == f"softdiff: error: {e.value}"
    assert e.value.exit_code == 1
