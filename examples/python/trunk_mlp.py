#!/usr/bin/python3
"""A small MLP that maps a tip goal to the Trunk's 8 cable tensions (docs/python.md
"PyTorch", issue 23).

The network (3 -> 16 -> 8, tanh; tensions = limits * sigmoid(output), so that every
output is a valid tension) is trained with Adam over a handful of goals: each
epoch runs the Trunk (configs/trunk.yaml) once per goal with the network's tensions,
constant over a short trajectory (default 10 steps of 0.01 s from rest, under gravity),
and back-propagates |tip_T - goal|^2 (mm^2, averaged over the goals) through
softdiff.torch.trajectory into the network's weights. Every run in an epoch keeps its
own recording, so one backward over the summed loss runs one adjoint per goal.
The goals are the tips reached with random tensions (reachable by construction; seed
--seed); one more such goal, not trained on, is reported at the end. Writes the loss per
epoch as a PNG (matplotlib, Agg).

    PYTHONPATH=build/python /usr/bin/python3 examples/python/trunk_mlp.py --threads 1 --out /tmp/trunk
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


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default=str(ROOT / "configs" / "trunk.yaml"))
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--goals", type=int, default=5, help="training goals")
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--lr", type=float, default=0.02)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--out", default=".", help="folder of the loss plot trunk_mlp_loss.png")
    args = p.parse_args(argv)
    if min(args.steps, args.goals, args.epochs) < 1:
        p.error("--steps, --goals and --epochs must be >= 1")
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)

    rollout = softdiff.Rollout(softdiff.load_scene(args.scene), threads=args.threads)
    if rollout.num_actuators != 8:
        p.error(f"the scene has {rollout.num_actuators} actuators, this example drives the Trunk's 8 cables")
    limits = torch.tensor(LIMITS, dtype=torch.float64)

    def tip_at_end(tensions):
        x = st.trajectory(rollout, actuation=tensions.expand(args.steps, 8))
        return st.effector(rollout, x, "tip")[-1]

    with torch.no_grad():
        rest = tip_at_end(torch.zeros(8, dtype=torch.float64))   # the tip with slack cables
        # Goals: tips reached with random tensions (each cable up to half its limit).
        goals = torch.stack([tip_at_end(limits * torch.tensor(rng.uniform(0, 0.5, 8)))
                             for _ in range(args.goals + 1)])
    train, held_out = goals[:-1], goals[-1]
    scale = 0.02   # m: goals enter the network as (goal - rest) / scale, O(1)

    net = torch.nn.Sequential(torch.nn.Linear(3, 16), torch.nn.Tanh(), torch.nn.Linear(16, 8)).double()
    with torch.no_grad():
        net[2].bias.fill_(-2.0)   # start at tensions ~0.12 of the limits

    def tensions_for(goal):
        return limits * torch.sigmoid(net((goal - rest) / scale))

    def loss_for(goal):
        return ((tip_at_end(tensions_for(goal)) - goal) * 1e3).pow(2).sum()

    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    losses = []
    start = time.perf_counter()
    for _ in range(args.epochs):
        opt.zero_grad()
        loss = sum(loss_for(g) for g in train) / len(train)
        loss.backward()   # one adjoint per goal, each over its own run
        losses.append(loss.item())
        opt.step()
    with torch.no_grad():
        final = (sum(loss_for(g) for g in train) / len(train)).item()
        held = loss_for(held_out).item()
    seconds = time.perf_counter() - start
    losses.append(final)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogy(range(len(losses)), losses, marker="o", ms=3)
    ax.set_xlabel("epoch (Adam)")
    ax.set_ylabel("mean |tip - goal|^2 (mm^2)")
    ax.set_title(f"Trunk: MLP goal -> 8 tensions, {len(train)} goals, {args.steps} steps")
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    png = out / "trunk_mlp_loss.png"
    fig.savefig(png, dpi=100)

    print(f"loss: {losses[0]:.6g} -> {final:.6g} mm^2 (mean over {len(train)} goals) in {args.epochs} epochs "
          f"({seconds:.1f} s)")
    print(f"held-out goal: distance {np.sqrt(held):.4g} mm")
    print(f"loss plot: {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
