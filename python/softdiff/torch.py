"""softdiff.torch: PyTorch interop (docs/python.md "PyTorch"; issue 23).

    import softdiff, torch
    import softdiff.torch as st
    rollout = softdiff.Rollout(softdiff.load_scene("configs/trunk.yaml"), theta="young")
    log_young = torch.tensor([13.0], dtype=torch.float64, requires_grad=True)
    tensions = torch.zeros(10, 8, dtype=torch.float64, requires_grad=True)  # (steps, n_actuators)
    x = st.trajectory(rollout, torch.exp(log_young), tensions)   # (steps + 1, n, 3) node positions
    tip = st.effector(rollout, x, "tip")                           # (steps + 1, 3)
    loss = ((tip[-1] - goal) ** 2).sum(); loss.backward()

trajectory() is a torch.autograd.Function: its forward runs the scene (Rollout.record:
the model with theta's values, the actuators' values per step replacing their
schedules) and keeps that run's recording; its backward is softdiff's adjoint over that
recording (Rollout.adjoint: diff::adjoint, one reverse sweep that recomputes each step)
with the incoming gradient of every frame as the loss's per-frame cotangent. Backward
does not run the forward again: the sweep recomputes each step from the recorded state
before it, bit for bit (recompute_mismatch 0; a warning otherwise), so the gradient is
the gradient of exactly the trajectory that forward returned.

Everything is float64 on the CPU. PyTorch is imported here only: `import softdiff` does
not need it.
"""
import warnings as _warnings

import numpy as _np
import torch as _torch

__all__ = ["trajectory", "effector", "RecomputeWarning"]


class RecomputeWarning(RuntimeWarning):
    """The adjoint's reverse sweep did not recompute the recorded run bit for bit."""


def _numpy(t):
    return None if t is None else t.detach().to(dtype=_torch.float64, device="cpu").contiguous().numpy()


class _Trajectory(_torch.autograd.Function):
    @staticmethod
    def forward(ctx, rollout, steps, theta, actuation, x0, v0):
        x, v, recording = rollout.record(steps, values=_numpy(theta), actuation=_numpy(actuation), x0=_numpy(x0),
                                         v0=_numpy(v0))
        ctx.rollout = rollout
        ctx.recording = recording   # this run's tape: backward differentiates exactly it
        ctx.set_materialize_grads(False)   # an unused output's gradient stays None (a zero cotangent)
        return _torch.from_numpy(x), _torch.from_numpy(v)

    @staticmethod
    def backward(ctx, grad_x, grad_v):
        _, _, need_theta, need_actuation, need_x0, need_v0 = ctx.needs_input_grad
        if grad_x is None and grad_v is None:
            return None, None, None, None, None, None
        g = ctx.rollout.adjoint(ctx.recording, bar_x=_numpy(grad_x), bar_v=_numpy(grad_v))
        if g["recompute_mismatch"] != 0:
            _warnings.warn(f"softdiff.torch: the adjoint recomputed the run {ctx.recording.id} with a difference of "
                           f"{g['recompute_mismatch']:.3g} (not bit for bit): the gradient is that of a run this close "
                           "to the forward's", RecomputeWarning, stacklevel=2)

        def out(need, key):
            return _torch.from_numpy(g[key]) if need else None

        return (None, None, out(need_theta, "theta"), out(need_actuation, "actuation"), out(need_x0, "x0"),
                out(need_v0, "v0"))


def _as_double(t, name):
    if t is None:
        return None
    if not isinstance(t, _torch.Tensor):
        t = _torch.as_tensor(_np.asarray(t, dtype=_np.float64))
    if t.device.type != "cpu":
        raise ValueError(f"{name}: softdiff runs on the CPU; got a tensor on {t.device}")
    return t.to(_torch.float64)   # differentiable: a float32 leaf gets its gradient cast back


def trajectory(rollout, theta=None, actuation=None, steps=None, x0=None, v0=None, velocities=False):
    """The scene's trajectory as a differentiable tensor.

    rollout: a softdiff.Rollout (the scene, its theta groups and threads).
    theta: (k,) the values of rollout.theta_columns (physical units: young in Pa, poisson,
      density kg/m^3, rayleigh_mass 1/s, rayleigh_stiffness s, friction), or None for
      the scene's values (then no gradient).
    actuation: (steps, n_actuators) every actuator's value at every step, in
      rollout.actuators' order and the actuator's own unit (cable: tension N; pressure:
      Pa; servo: force N, or torque N m for a rotation servo), replacing its schedule: step k (1-based) uses row k - 1 (the value at its
      end, t_k, as the schedules are sampled); None: the schedules (rollout.schedule).
    steps: the number of steps (needed when actuation is None; else its rows).
    x0, v0: (n, 3) the initial positions and velocities (None: the scene's).
    velocities: also return the velocities.
    Returns x (steps + 1, n, 3), frame 0 the initial state, nodes of every soft body in
    scene order (rollout.nodes(body) is a body's slice); with velocities (x, v).
    Gradients flow to theta, actuation, x0 and v0 from any frames of x and v.
    """
    theta = _as_double(theta, "theta")
    actuation = _as_double(actuation, "actuation")
    x0 = _as_double(x0, "x0")
    v0 = _as_double(v0, "v0")
    if actuation is not None:
        if actuation.dim() != 2:
            raise ValueError(f"actuation: shape (steps, {rollout.num_actuators}) expected, got {tuple(actuation.shape)}")
        if steps is not None and steps != actuation.shape[0]:
            raise ValueError(f"steps={steps} but actuation has {actuation.shape[0]} rows (one per step)")
        steps = actuation.shape[0]
    if steps is None:
        raise ValueError("steps: give the number of steps (or an actuation sequence, one row per step)")
    x, v = _Trajectory.apply(rollout, int(steps), theta, actuation, x0, v0)
    return (x, v) if velocities else x


def effector(rollout, x, name):
    """An effector's positions along a trajectory x (..., n, 3): (..., 3), the embedded
    point sum_a w_a x[nodes[a]] (differentiable)."""
    nodes, weights = rollout.effector(name)
    w = _torch.as_tensor(weights, dtype=x.dtype)
    return (x[..., _torch.as_tensor(nodes), :] * w[:, None]).sum(dim=-2)
