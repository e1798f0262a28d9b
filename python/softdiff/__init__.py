"""softdiff: differentiable soft-robot simulation (FEM, frictional contact, rigid bodies).

The Python API (docs/python.md):

    import softdiff
    scene = softdiff.load_scene("configs/trunk.yaml",
                                overrides={"bodies.trunk.material.young": 9.0e5})
    sim = softdiff.Simulator(scene, threads=1)
    traj = sim.run(5)   # body name -> numpy (6, n, 3); rigid bodies (6, 7)
    sim.step(); sim.time; sim.x("trunk"); sim.v("trunk")

Errors: softdiff.SceneError (a ValueError; the CLI's exit code 2) with the CLI's
`FILE:LINE:COL: KEY.PATH: message`, softdiff.StepError (a RuntimeError; exit code 1)
with the CLI's message.
"""
# The extension first: it pins the BLAS that the CLI uses (OpenBLAS, pthreads) through
# its RPATH, which only works if no other module loaded libblas.so.3 before it
# (docs/python.md "BLAS").
from ._softdiff import (  # noqa: F401
    ConvergenceWarning,
    Scene,
    SceneError,
    SceneWarning,
    Simulator,
    StepError,
    __version__,
    thread_plan,
)
from ._softdiff import _load_scene, _read_output
from ._softdiff import Recording, Rollout  # noqa: F401  torch support (ptorch): softdiff.torch's runs
from ._softdiff import _calibrate, _control  # calibrate/control (pycal)
from ._softdiff import _simulate  # output files (pyout)

import math as _math
import numbers as _numbers
import os as _os
from collections.abc import Mapping as _Mapping

__all__ = ["load_scene", "read_result", "Result", "calibrate", "control", "Scene", "Simulator", "SceneError", "StepError", "ConvergenceWarning", "SceneWarning", "thread_plan",
           "__version__"]
__all__ += ["Rollout", "Recording"]  # torch support (ptorch)
__all__ += ["simulate"]  # output files (pyout)


def __getattr__(name):
    # softdiff.torch (python/softdiff/torch.py, docs/python.md "PyTorch") is imported on
    # first use: `import softdiff` does not need PyTorch.
    if name == "torch":
        import importlib
        return importlib.import_module(".torch", __name__)
    raise AttributeError(f"module 'softdiff' has no attribute {name!r}")


def _yaml_value(value):
    """A Python value as the VALUE of a --set KEY=VALUE (YAML flow syntax)."""
    if value is None:
        return "null"  # --set KEY=null: back to the default (docs/scene.md)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not _math.isfinite(value):
            raise SceneError(f"--set: {value!r} is not a finite number")
        return repr(value)  # shortest text that reads back as the same double
    if isinstance(value, str):
        return value
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_yaml_value(v) for v in value) + "]"
    try:  # numpy scalars and arrays
        import numpy
        if isinstance(value, numpy.ndarray):
            return _yaml_value(value.tolist())
        if isinstance(value, numpy.generic):
            return _yaml_value(value.item())
    except ImportError:
        pass
    raise TypeError(f"override value {value!r} of type {type(value).__name__}: "
                    "give a number, a string, a bool, None or a list of those")


def load_scene(path, overrides=None):
    """Load and validate a scene file (docs/scene.md), as `softdiff simulate` does.

    overrides: {"KEY.PATH": value} (or a list of "KEY.PATH=VALUE" strings), the CLI's
    `--set KEY=VALUE`, applied in order before validation. Raises SceneError with the
    CLI's message (`FILE:LINE:COL: KEY.PATH: message`, or `--set: PATH: message`).
    """
    if overrides is None:
        sets = []
    elif isinstance(overrides, _Mapping):
        sets = []
        for key, value in overrides.items():
            if not isinstance(key, str):
                raise TypeError(f"override key {key!r}: a string KEY.PATH, e.g. 'bodies.beam.material.young'")
            sets.append(f"{key}={_yaml_value(value)}")
    elif isinstance(overrides, str):
        raise TypeError("overrides: a dict {'KEY.PATH': value} or a list of 'KEY.PATH=VALUE' strings")
    else:
        sets = [str(s) for s in overrides]
    return _load_scene(_os.fspath(path), sets)


class Result:
    """A softdiff HDF5 output (docs/output.md), read whole (softdiff.read_result).

    status: the file's status ("complete", "diverged: ...", ...); time: (T,) frame times;
    bodies: body name -> {"x": (T, n, 3), "v", "rest", "tets", "surface", ... as in the
    file; rigid bodies "position", "orientation", ...}; jacobians: theta group -> (rows, k);
    data: every group of the file as nested dicts (but /xdmf); attributes: the root's
    numeric attributes. Arrays are float64 but the index datasets (tets, surface,
    /contact/offsets, /contact/pair, /contact/mode), which are int64.
    """

    _INDEX = {"tets", "surface", "offsets", "pair", "mode"}

    def __init__(self, path, raw):
        self.path = path
        self.status = raw["status"]
        self.attributes = dict(raw["attributes"])
        self.data = self._convert(raw["data"])
        self.time = self.data.get("time")
        self.bodies = self.data.get("bodies", {})
        self.jacobians = self.data.get("jacobians", {})

    @classmethod
    def _convert(cls, group):
        out = {}
        for name, value in group.items():
            if isinstance(value, dict):
                out[name] = cls._convert(value)
            elif name in cls._INDEX:
                out[name] = value.astype("int64")
            else:
                out[name] = value
        return out

    def __repr__(self):
        frames = 0 if self.time is None else len(self.time)
        return f"<softdiff.Result {self.path}: {self.status}, {frames} frames, bodies {sorted(self.bodies)}>"


def read_result(path):
    """Read a softdiff HDF5 output (docs/output.md) into a Result. Raises
    FileNotFoundError for a missing file, ValueError for a file that is not a softdiff
    output (not HDF5, or no root attribute `status`)."""
    path = _os.fspath(path)
    return Result(path, _read_output(path))


# --- calibrate/control (pycal) ---
# softdiff.calibrate() and softdiff.control(): the CLI's commands with its options
# (docs/python.md "calibrate and control"; optim/calibrate_run.hpp, optim/control_run.hpp).
# Python values become the CLI's option strings here: lists joined with commas, floats
# written with repr (the shortest text that reads back as the same double).

def _scene_and_sets(scene, set):
    """The scene file and its --set strings: a Scene's path and overrides, then `set`."""
    if isinstance(scene, Scene):
        path, sets = scene.path, list(scene.overrides)
    else:
        path, sets = _os.fspath(scene), []
    if set is not None:
        if isinstance(set, str):
            set = [set]
        if isinstance(set, _Mapping):
            for key, value in set.items():
                sets.append(f"{key}={_yaml_value(value)}")
        else:
            sets.extend(str(s) for s in set)
    return path, sets


def _number_text(value):
    """A number as the CLI's text: integers as they are, floats with repr."""
    if isinstance(value, str):
        return value
    if isinstance(value, _numbers.Integral) and not isinstance(value, bool):
        return str(int(value))
    try:
        return repr(float(value))
    except (TypeError, ValueError):
        raise TypeError(f"{value!r}: expected a number") from None


def _list_text(value, number=False):
    """A CLI list option: a string as it is, a sequence joined with commas."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value
    if isinstance(value, _os.PathLike):
        return _os.fspath(value)
    return ",".join(_number_text(v) if number else str(v) for v in value)


def _output(output, force):
    """output= and force= as the CLI's -o and --force: "" for no file (None)."""
    if output is None:
        if force:
            raise ValueError("force=True: only with output= (the CLI's --force overwrites its -o file)")
        return ""
    output = _os.fspath(output)
    if not output:
        raise ValueError("output='': expected a file name (None: no file)")
    return output


def _command(name, **kwargs):
    """The output file's `command` attribute (docs/output.md): the Python call."""
    args = ", ".join(f"{k}={v!r}" for k, v in kwargs.items())
    return f"python: softdiff.{name}({args})"


def calibrate(scene, param, target=None, markers=None, frames="all", init=None, max_iterations=50,
              tolerance=1e-10, set=None, threads=1, strict=False, output=None, force=False):
    """Identify material parameters from an observed motion: `softdiff calibrate` (docs/cli.md).

    scene: a Scene (load_scene: its overrides are the --set strings) or a path. param:
    "young,poisson" or a list of names (the CLI's --param). target: a softdiff HDF5
    trajectory (--target) or markers: a CSV (--markers). frames: "all", "last" or a list
    of frame indices. init: initial values (a list, or the CLI's "V,V" text). set: more
    --set overrides (a dict or "KEY=VALUE" strings). threads: as Simulator (0: all cores).
    output: the CLI's -o file (the scene simulated with the identified parameters plus
    /calibration, docs/output.md; None: no file); an existing file is refused (SceneError,
    the CLI's message) unless force=True (--force).
    Returns the dict that `calibrate --json` prints (output: the file, or None) plus
    "notes" (the CLI's notes on the target). Bad input raises SceneError with the CLI's
    message, a failed run StepError; not converging is `converged` False (the CLI exits 1).
    """
    out = _output(output, force)
    path, sets = _scene_and_sets(scene, set)
    if isinstance(frames, int):
        frames = [frames]
    command = _command("calibrate", scene=path, param=param, target=target, markers=markers, frames=frames, init=init,
                       max_iterations=max_iterations, tolerance=tolerance, set=sets, output=out, force=force)
    return _calibrate(path, sets, _list_text(param), _list_text(target), _list_text(markers),
                      _list_text(frames), _list_text(init, number=True), int(max_iterations), float(tolerance),
                      int(threads), bool(strict), out, bool(force), command)


def control(scene, target, effector=None, steps=None, weights="1,0", axes="xyz", regularization=1e-6, filter=1.0,
            shared_actuation=False, max_actuation=False, set=None, threads=1, strict=False, output=None,
            force=False):
    """Drive an effector to a goal by inverse dynamics: `softdiff control` (docs/cli.md).

    target: a point (x, y, z) in metres (a sequence, or the CLI's "X,Y,Z") or the path of
    a CSV of timed goals (time,x,y,z). weights: (alpha, beta) or "ALPHA,BETA". The other
    options are the CLI's (dashes as underscores). Returns the dict that `control --json`
    prints (output None) plus the /control series of the CLI's file as numpy arrays, one
    row per written frame (output.every), frame 0 first: time, goal (T, 3), distance,
    actuation (T, n_a), contact_force_norm (with contact), kkt_residual. Bad input raises
    SceneError with the CLI's message, a failed step StepError. output: the CLI's -o file
    (None: no file); force=True overwrites an existing one (--force).
    """
    out = _output(output, force)
    path, sets = _scene_and_sets(scene, set)
    if isinstance(target, (str, _os.PathLike)):
        target = _os.fspath(target)
    else:
        target = _list_text(target, number=True)
    command = _command("control", scene=path, target=target, effector=effector, steps=steps, weights=weights, axes=axes,
                       regularization=regularization, filter=filter, shared_actuation=shared_actuation,
                       max_actuation=max_actuation, set=sets, output=out, force=force)
    return _control(path, sets, target, effector or "", None if steps is None else int(steps),
                    _list_text(weights, number=True), axes, float(regularization), float(filter),
                    bool(shared_actuation), bool(max_actuation), int(threads), bool(strict), out, bool(force), command)


def simulate(scene, output=None, steps=None, duration=None, dt=None, set=None, jacobian=None, force=False, threads=1,
             strict=False):
    """Run a scene and write its output file: `softdiff simulate SCENE -o FILE` (docs/cli.md).

    output: the file (None: the scene's output.file, else <scene stem>.h5 in the current
    folder, as the CLI). steps, duration, dt: --steps, --duration, --dt. jacobian: the
    theta of --jacobian ("young,poisson" or a list): /jacobians/<theta> in the file.
    force: --force. Returns the dict that `simulate --json` prints but "bodies" (the
    states are in the file: read_result). Bad input raises SceneError with the CLI's
    message (an existing file without force=True included), a failed run StepError (the
    file is finished as the CLI finishes it, where the frames are named in the message).
    """
    path, sets = _scene_and_sets(scene, set)
    out = "" if output is None else _os.fspath(output)
    command = _command("simulate", scene=path, output=out, steps=steps, duration=duration, dt=dt, set=sets,
                       jacobian=jacobian, force=force)
    return _simulate(path, sets, None if steps is None else int(steps), None if duration is None else float(duration),
                     None if dt is None else float(dt), out, bool(force), _list_text(jacobian), int(threads),
                     bool(strict), command)
