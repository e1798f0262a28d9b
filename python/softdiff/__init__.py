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

import math as _math
import os as _os
from collections.abc import Mapping as _Mapping

__all__ = ["load_scene", "read_result", "Result", "Scene", "Simulator", "SceneError", "StepError", "ConvergenceWarning", "SceneWarning", "thread_plan",
           "__version__"]
__all__ += ["Rollout", "Recording"]  # torch support (ptorch)


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
