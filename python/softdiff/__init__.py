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
from ._softdiff import _load_scene

import math as _math
import os as _os
from collections.abc import Mapping as _Mapping

__all__ = ["load_scene", "Scene", "Simulator", "SceneError", "StepError", "ConvergenceWarning", "SceneWarning", "thread_plan",
           "__version__"]


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
