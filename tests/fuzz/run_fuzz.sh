#!/usr/bin/env bash
# Runs one libFuzzer target for a bounded time (ctest: fuzz_gmsh, fuzz_scene).
# Usage: run_fuzz.sh FUZZER SEED_CORPUS WORK_DIR SECONDS
# New inputs go to WORK_DIR/corpus (the seed corpus in the source tree is read only);
# a crash, sanitizer report, timeout (10 s per input) or memory blow-up (2 GB) fails
# the test and leaves the input in WORK_DIR (crash-*, timeout-*, oom-*): minimize it
# with `FUZZER -minimize_crash=1 -max_total_time=60 FILE`, add it to the seed corpus
# and a regression test (tests/fuzz/README.md).
set -euo pipefail
fuzzer=$1 seeds=$2 work=$3 seconds=$4
mkdir -p "$work/corpus"
exec "$fuzzer" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
  -artifact_prefix="$work/" "$work/corpus" "$seeds"
