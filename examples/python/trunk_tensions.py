#!/usr/bin/python3
"""The Trunk's 8 cable tensions by torch.optim (docs/python.md "PyTorch", issue 23).

Finds the 8 constant tensions that bring the Trunk's tip effector (configs/trunk.yaml)
to a goal at the end of a short trajectory (default 15 steps of 0.01 s from rest, under
gravity), by gradient descent (Adam, or LBFGS) through softdiff.torch.trajectory: each
iteration is one forward run and one adjoint sweep. Writes the loss per iteration as a
PNG (matplotlib, Agg) and prints the final distance.

Tensions: t = limit * sigmoid(z), so that every iterate is a valid tension (cables only
pull, 0 <= t <= the scene's limits: 0.25 N for the long cables cableL*, 0.45 N for the
short ones cableS*). The default goal is the tip after the same 15 steps with the
tensions (0.2, 0, 0, 0.1, 0.3, 0, 0, 0.1) N (reachable by construction); --goal X Y Z
(metres) sets another. Loss: |tip_T - goal|^2 in mm^2.

    PYTHONPATH=build/python /usr/bin/python3 examples/python/trunk_tensions.py --threads 1 --out /tmp/trunk
"""
import argparse
import pathlib
import sys
import time

import softdiff  # before numpy and torch: the CLI's BLAS (docs/python.md "BLAS")
import numpy as np
import torch

import softdiff.torch as st

ROOT = pathlib.Path(__file__).resolve().parents[2]
LIMITS = [0.25] * 4 + [0.45] * 4   # configs/trunk.yaml: cableL0-3, cableS0-3 (N)
REFERENCE = [0.2, 0.0, 0.0, 0.1, 0.3, 0.0, 0.0, 0.1]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default=str(ROOT / "configs" / "trunk.yaml"))
    p.add_argument("--steps", type=int, default=15, help="trajectory length (steps of the scene's dt)")
    p.add_argument("--iterations", type=int, default=40)
    p.add_argument("--optimizer", choices=["adam", "lbfgs"], default="adam")
    p.add_argument("--lr", type=float, default=0.5, help="Adam's learning rate on z (t = limit sigmoid(z))")
    p.add_argument("--decay", type=float, default=0.92, help="Adam's learning rate factor per iteration")
    p.add_argument("--goal", type=float, nargs=3, metavar=("X", "Y", "Z"), help="tip goal (m); default: reachable")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", default=".", help="folder of the loss plot trunk_tensions_loss.png")
    args = p.parse_args(argv)
    if args.steps < 1 or args.iterations < 1:
        p.error("--steps and --iterations must be >= 1")

    rollout = softdiff.Rollout(softdiff.load_scene(args.scene), threads=args.threads)
    if rollout.num_actuators != 8:
        p.error(f"the scene has {rollout.num_actuators} actuators, this example drives the Trunk's 8 cables")
    limits = torch.tensor(LIMITS, dtype=torch.float64)

    def tip_at_end(tensions):
        x = st.trajectory(rollout, actuation=tensions.expand(args.steps, 8))   # constant tensions over the run
        return st.effector(rollout, x, "tip")[-1]

    with torch.no_grad():
        goal = (torch.tensor(args.goal, dtype=torch.float64) if args.goal
                else tip_at_end(torch.tensor(REFERENCE, dtype=torch.float64)))
    z = torch.full((8,), -2.0, dtype=torch.float64, requires_grad=True)   # t = 0.12 limit to start

    def loss_of(z):
        return ((tip_at_end(limits * torch.sigmoid(z)) - goal) * 1e3).pow(2).sum()   # mm^2

    losses = []
    start = time.perf_counter()
    if args.optimizer == "adam":
        opt = torch.optim.Adam([z], lr=args.lr)
        # The learning rate decays by `--decay` per iteration: Adam's fixed step overshoots
        # and circles the goal (a loss going up and down by 10x) once it is close.
        schedule = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=args.decay)
        for _ in range(args.iterations):
            opt.zero_grad()
            loss = loss_of(z)
            loss.backward()
            losses.append(loss.item())
            opt.step()
            schedule.step()
    else:
        opt = torch.optim.LBFGS([z], lr=1.0, max_iter=1, line_search_fn="strong_wolfe")

        def closure():
            opt.zero_grad()
            loss = loss_of(z)
            loss.backward()
            return loss

        for _ in range(args.iterations):
            losses.append(opt.step(closure).item())
    with torch.no_grad():
        final = loss_of(z).item()
    seconds = time.perf_counter() - start
    losses.append(final)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(range(len(losses)), losses, marker="o", ms=3)
    ax.set_xlabel(f"iteration ({args.optimizer})")
    ax.set_ylabel("|tip - goal|^2 (mm^2)")
    ax.set_title(f"Trunk: 8 cable tensions, tip goal after {args.steps} steps")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    png = out / "trunk_tensions_loss.png"
    fig.savefig(png, dpi=100)

    tensions = (limits * torch.sigmoid(z)).detach().numpy()
    print("tensions (N): " + " ".join(f"{n}={t:.4f}" for n, t in zip(rollout.actuators, tensions)))
    print(f"goal (m): {goal.numpy()}")
    print(f"loss: {losses[0]:.6g} -> {final:.6g} mm^2 in {args.iterations} iterations ({seconds:.1f} s)")
    print(f"final distance: {np.sqrt(final):.4g} mm")
    print(f"loss plot: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
