"""The Gripper control table on configs/gripper_lift.yaml (docs/method.md "The Gripper
lifting its free object"): for each `softdiff control` output given, the last 10 steps'
means of |X_e| (cm) and |lambda_c,nodes| (cN), the servo torque at the end (N m), the
object's drop from its start to the last frame (mm) and its vertical speed there (mm/s).

    /usr/bin/python3 scripts/analysis/gripper_table.py heuristic.h5 optimized.h5 ...
"""
import sys

import h5py


def row(path):
    with h5py.File(path, "r") as f:
        d = 100 * f["control/distance"][:]
        F = 100 * f["control/contact_force_norm"][:]
        a = f["control/actuation"][:, 0]
        p = f["bodies/object/position"][:]
        t = f["time"][:]
    drop = 1e3 * (p[0, 2] - p[-1, 2])
    v = 1e3 * (p[-1, 2] - p[-2, 2]) / (t[-1] - t[-2])
    return d[-10:].mean(), F[-10:].mean(), a[-1], drop, v


if __name__ == "__main__":
    print("%-24s %10s %12s %10s %10s %10s" % ("run", "|X_e| cm", "|lam_c| cN", "tau_end", "drop mm", "v mm/s"))
    for path in sys.argv[1:]:
        print("%-24s %10.3f %12.3f %10.4f %10.2f %10.2f" % ((path,) + row(path)))
