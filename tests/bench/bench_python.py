"""The Python module's per-step overhead (issue 23: "a Python step() loop costs at most
1.05x the C++ loop on the Trunk, measured as a ratio in one run"; docs/performance.md
"Python").

    scripts/bench python [--threads 1] [--steps 100] [--repeats 7] [--block 5] [--scene configs/trunk.yaml]

A = the C++ loop: sim.advance(n), the library's step loop in this process with no Python
    between the steps (the GIL released once);
B = the Python loop: for _ in range(n): sim.step().
Each repeat builds two fresh simulators (not timed) and advances them together, --block
steps at a time (A's block, then B's, the order alternating from block to block), so
that a drift of the machine's load touches both alike. Reported: the medians over the
repeats of A's and B's total times, their ratio B / A (the figure), the per-repeat
ratios, the median of the blocks' ratios, and the absolute per-step difference; then a
control, the same measurement with advance() for both (its ratio is 1 but for the
noise of this machine in this run: the resolution of the figure). The same loops on a scene
whose step costs microseconds (the rigid stack without contact) give the binding's
own cost per step, which the Trunk's ratio divides by its step time. A benchmark, not a
test: it asserts nothing about time; it checks that both loops reached the same state
bit for bit (they do the same work). uptime is printed before and after.
"""
import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import time

import softdiff  # before numpy (docs/python.md "BLAS")
import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[2]


def uptime():
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def measure(scene, steps, repeats, threads, block, control=False):
    """Per repeat: two fresh simulators A, B (not timed) advanced together, `block`
    steps at a time, A by advance(block), B by block step() calls, the order of the two
    alternating from block to block: the two loops run interleaved at a fine grain, so
    that a change of the machine's load touches both alike; which simulator is built
    first alternates from repeat to repeat. control: B runs advance() too (A against A:
    the noise of the ratio in this run)."""
    a_times, b_times, block_ratios, fastest = [], [], [], {"A": float("inf"), "B": float("inf")}
    same = True
    for r in range(repeats):
        sims = {w: softdiff.Simulator(scene, threads=threads) for w in ("AB" if r % 2 == 0 else "BA")}
        totals = {"A": 0.0, "B": 0.0}
        for i in range(steps // block):
            took = {}
            for which in (("A", "B") if (r + i) % 2 == 0 else ("B", "A")):
                sim = sims[which]
                t0 = time.perf_counter()
                if which == "A" or control:
                    sim.advance(block)
                else:
                    for _ in range(block):
                        sim.step()
                took[which] = time.perf_counter() - t0
                totals[which] += took[which]
                fastest[which] = min(fastest[which], took[which] / block)
            block_ratios.append(took["B"] / took["A"])
        a_times.append(totals["A"])
        b_times.append(totals["B"])
        finals = {w: [s.x(n) for n in s.bodies] + [s.v(n) for n in s.bodies] for w, s in sims.items()}
        same = same and all(np.array_equal(x, y) for x, y in zip(finals["A"], finals["B"]))
    ratios = [b / a for a, b in zip(a_times, b_times)]
    return {
        "A": statistics.median(a_times), "B": statistics.median(b_times),
        "ratio": statistics.median(b_times) / statistics.median(a_times),
        "ratios": ratios, "block_ratio": statistics.median(block_ratios), "blocks": len(block_ratios), "same": same,
        "fastest_us": {w: t * 1e6 for w, t in fastest.items()},
        "per_step_us": (statistics.median(b_times) - statistics.median(a_times)) / (steps // block * block) * 1e6,
    }


def report(label, steps, m):
    print(f"{label}: {steps} steps x {len(m['ratios'])} repeats")
    print(f"  C++ loop (advance) median {m['A'] * 1e6 / steps:.4g} us/step, Python loop (step) median "
          f"{m['B'] * 1e6 / steps:.4g} us/step")
    print(f"  ratio Python / C++ (medians): {m['ratio']:.4f}; per repeat: "
          + ", ".join(f"{x:.4f}" for x in m["ratios"])
          + f" (min {min(m['ratios']):.4f}, median {statistics.median(m['ratios']):.4f}, max {max(m['ratios']):.4f})")
    print(f"  median of the {m['blocks']} interleaved blocks' ratios: {m['block_ratio']:.4f}")
    print(f"  difference per step: {m['per_step_us']:.2f} us of the medians; {m['fastest_us']['B'] - m['fastest_us']['A']:.2f} us "
          f"of the fastest blocks (C++ {m['fastest_us']['A']:.4g} us/step, Python {m['fastest_us']['B']:.4g} us/step); "
          f"same final state bit for bit: {'yes' if m['same'] else 'NO'}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=str(ROOT / "configs" / "trunk.yaml"))
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--block", type=int, default=5, help="steps per interleaved block")
    p.add_argument("--tiny-steps", type=int, default=20000,
                   help="steps of the microsecond scene (the binding's own cost per step)")
    args = p.parse_args()
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip() or "unknown"
    print(f"== {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} commit {commit}, --threads {args.threads}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}")
    print(f"== uptime: {uptime()}")
    print(f"== BLAS: {softdiff.thread_plan()['blas']}")
    scene = softdiff.load_scene(args.scene)
    m = measure(scene, args.steps, args.repeats, args.threads, args.block)
    report(f"{scene.name} ({args.scene})", args.steps, m)
    c = measure(scene, args.steps, args.repeats, args.threads, args.block, control=True)
    report("control: the same with advance() for both loops (the ratio's noise in this run)", args.steps, c)
    tiny = softdiff.load_scene(ROOT / "configs" / "rigid_stack.yaml", overrides={"contact.enabled": False})
    t = measure(tiny, args.tiny_steps, args.repeats, args.threads, args.tiny_steps // 20)
    report("rigid stack without contact (the binding's own cost per step)", args.tiny_steps, t)
    print(f"== uptime: {uptime()}")
    return 0 if m["same"] and t["same"] and c["same"] else 1


if __name__ == "__main__":
    sys.exit(main())
