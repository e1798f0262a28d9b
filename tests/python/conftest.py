"""Fixtures of the Python module's tests (run by ctest's python_pytest, label python:
PYTHONPATH=build/python /usr/bin/python3 -m pytest -q tests/python)."""
import os
import pathlib
import subprocess

import pytest

# softdiff before numpy and h5py: the extension then loads the CLI's BLAS (OpenBLAS
# with pthreads, through its RPATH) and the trajectories can be compared with the
# CLI's bit for bit (docs/python.md "BLAS").
import softdiff  # noqa: F401

ROOT = pathlib.Path(os.environ.get("SOFTDIFF_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


def _cli_path():
    if "SOFTDIFF_CLI" in os.environ:
        return pathlib.Path(os.environ["SOFTDIFF_CLI"])
    return ROOT / "build" / "bin" / "softdiff"


@pytest.fixture(scope="session")
def root():
    return ROOT


@pytest.fixture(scope="session")
def cli():
    """Runs the softdiff CLI: cli(args, cwd) -> CompletedProcess (text)."""
    exe = _cli_path()
    if not exe.exists():
        pytest.fail(f"the CLI {exe} is not built (cmake --build build --target softdiff_cli)")

    def run(args, cwd):
        env = dict(os.environ, OMP_NUM_THREADS="1")
        return subprocess.run([str(exe)] + [str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=120)

    return run


# tests/app/test_cli_control.cpp's scene: a beam whose tip a servo pulls sideways (no
# contact); control's and the output's tests run it.
_SERVO_BEAM = """softdiff: 1
simulation: {{dt: 0.01, steps: {steps}, gravity: [0, 0, 0]}}
bodies:
  - name: beam
    mesh: {mesh}
    material: {{law: corotational, young: 2.0e5, poisson: 0.4, density: 1000}}
    damping: {{rayleigh_mass: 5}}
    fixed:
      - group: clamp
    actuators:
      - {{name: pull, type: servo, nodes: {{box: [0.19, -1, -1, 1, 1, 1]}}, direction: [0, 1, 0], force: 0, limits: [-0.05, 0.05]}}
    effectors:
      - {{name: tip, point: [0.2, 0.01, 0.01]}}
"""


@pytest.fixture(scope="session")
def servo_beam_scene():
    """write(path, steps) -> path: the servo beam's scene with `steps` steps."""
    def write(path, steps):
        path.write_text(_SERVO_BEAM.format(steps=steps, mesh=ROOT / "meshes" / "beam.msh"))
        return path

    return write
