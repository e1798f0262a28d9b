#!/usr/bin/python3
"""Accuracy-vs-time benchmark of softdiff: the cantilever beam against CalculiX, and
frictional contact against analytic answers (docs/accuracy.md).

    /usr/bin/python3 scripts/accuracy/run.py [--out DIR] [--quick] [--only beam|beam-static|contact|bdf2]
                                             [--threads N] [--resume]

  --out DIR     output folder (default: accuracy/ in the current folder): beam.csv,
                beam_error_vs_time.png, contact.csv, contact_error_vs_time.png,
                summary.txt; meshes/ and runs/ (one folder per run) are scratch
  --quick       a small sweep (a few minutes): coarse meshes, fewer time steps and
                tolerances, coarse references (checks the pipeline, not the numbers)
  --only        run one part (beam-static: the beam's static cases only, every element)
  --threads N   threads of every run, both tools (default 1: the machine is shared)
  --resume      reuse the stored result of a run whose inputs are unchanged
                (its measured times included) instead of running it again

The softdiff binary is $SOFTDIFF_BIN (default <repo>/build/bin/softdiff); CalculiX is
`ccx` on PATH (Debian: apt-get install calculix-ccx).
"""
import argparse
import datetime
import os
import platform
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from common import RunCache, log, softdiff_bin, which  # noqa: E402


def machine():
    cpu = "unknown cpu"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        ccx_v = subprocess.run(["ccx", "-v"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               timeout=20).stdout.decode(errors="replace").strip().splitlines()
        ccx_v = [l for l in ccx_v if "ersion" in l][:1] or ccx_v[:1]
    except (OSError, subprocess.TimeoutExpired):
        ccx_v = ["?"]
    try:
        sd_v = subprocess.run([softdiff_bin(), "--version"], stdout=subprocess.PIPE,
                              timeout=20).stdout.decode().splitlines()[0]
    except (OSError, subprocess.TimeoutExpired, IndexError):
        sd_v = "?"
    return "%s, %d cores (os.cpu_count), %s; %s; CalculiX: %s" % (
        cpu, os.cpu_count() or 0, platform.platform(), sd_v, ccx_v[0].strip())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="accuracy")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", choices=["beam", "beam-static", "contact", "bdf2"])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--resume", action="store_true")
    a = ap.parse_args()

    if not os.path.exists(softdiff_bin()):
        sys.exit("accuracy: no softdiff binary at %s (set SOFTDIFF_BIN or build it)" % softdiff_bin())
    if a.only not in ("contact", "bdf2") and not which("ccx"):
        sys.exit("accuracy: CalculiX `ccx` not found (Debian: apt-get install calculix-ccx)")
    if not which("gmsh"):
        sys.exit("accuracy: gmsh not found")
    out = os.path.abspath(a.out)
    os.makedirs(out, exist_ok=True)
    cache = RunCache(out, a.resume)
    t0 = time.time()
    started = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    header = ["softdiff accuracy benchmark, %s" % started,
              "command: %s" % os.environ.get("SOFTDIFF_ACCURACY_COMMAND",
                                             " ".join(["/usr/bin/python3", os.path.relpath(sys.argv[0])] + sys.argv[1:])),
              "softdiff binary: %s" % softdiff_bin(),
              "machine: %s" % machine(),
              "threads per run: %d (softdiff --threads, OMP/OpenBLAS; CalculiX OMP_NUM_THREADS, "
              "CCX_NPROC_EQUATION_SOLVER); load average at start: %s"
              % (a.threads, " ".join("%.2f" % x for x in os.getloadavg())),
              ""]
    parts = []
    if a.only in (None, "beam", "beam-static"):
        import beam
        tb = time.time()
        _, text = beam.run(out, cache, a.threads, a.quick, static_only=a.only == "beam-static")
        parts.append(text + "\n\nbeam part: %.0f s wall" % (time.time() - tb))
    if a.only in (None, "contact"):
        import contact
        tc = time.time()
        text = contact.run(out, cache, a.threads, a.quick)
        parts.append(text + "\n\ncontact part: %.0f s wall" % (time.time() - tc))
    if a.only in (None, "bdf2"):
        import bdf2_beam
        td = time.time()
        text = bdf2_beam.run(out, cache, a.threads, a.quick)
        parts.append(text + "\n\nbdf2 part: %.0f s wall" % (time.time() - td))
    footer = ["", "total: %.0f s wall; load average at the end: %s"
              % (time.time() - t0, " ".join("%.2f" % x for x in os.getloadavg()))]
    text = "\n".join(header) + "\n\n".join(parts) + "\n".join(footer) + "\n"
    name = "summary.txt" if a.only is None else "summary_%s.txt" % a.only
    with open(os.path.join(out, name), "w") as f:
        f.write(text)
    print(text)


if __name__ == "__main__":
    main()
