#!/usr/bin/env bash
# The README's "A short tour", run top to bottom twice in a row in a fresh folder (the
# second pass must succeed too: every line overwrites its outputs). Slow lines are
# shortened: simulations and control runs to a few steps (the calibration targets, so
# calibrate, follow), the demos with --steps, the library example to 6 steps and 4
# iterations (its ctest case). Paths of the tour (scripts/, configs/, meshes/, build/)
# are taken from the source tree and SOFTDIFF_BUILD_DIR (default SOURCE_DIR/build).
# check-grad to 1 step. Each line's time is printed. TOUR_FULL=1 runs the lines as written (no shortening),
# TOUR_PASSES=1 once: how the README's times were measured.
# Usage: run_tour.sh SOURCE_DIR [BUILD_DIR]
set -euo pipefail
src="$(cd "$1" && pwd)"
export SOFTDIFF_BUILD_DIR="${2:-${SOFTDIFF_BUILD_DIR:-$src/build}}"
steps="${TOUR_STEPS:-3}"

# The tour: the first ```sh block after "## A short tour", continuation lines joined.
tour="$(awk '/^## A short tour/ {in_section = 1} in_section && /^```sh/ {in_block = 1; next}
             in_block && /^```/ {exit} in_block' "$src/README.md" | sed -e ':a' -e '/\\$/N; s/\\\n//; ta')"
[[ -n "$tour" ]] || { echo "run_tour: no tour block in $src/README.md" >&2; exit 1; }

# One command of the tour, shortened, with the source tree's paths.
shorten() {
  local c="$1"
  c="$(sed -E 's/[[:space:]]+#[[:space:]].*$//' <<<"$c")"  # the comment
  [[ "${TOUR_FULL:-0}" == 1 ]] || case "$c" in
    "scripts/softdiff simulate "*static*) ;;  # a static scene: its load steps are few
    "scripts/softdiff check-grad "*)
      c="$(sed -E "s/--steps [0-9]+/--steps 1/" <<<"$c")" ;;
    "scripts/softdiff simulate "* | "scripts/softdiff control "* | scripts/control_*_demo* | "scripts/calibration_demo"*)
      if [[ "$c" == *"--steps "* ]]; then
        c="$(sed -E "s/--steps [0-9]+/--steps $steps/" <<<"$c")"
      else
        c="$c --steps $steps"
      fi ;;
    build/bin/softdiff_example_effector_gradient*)
      c="$(sed -E 's/ [0-9]+ [0-9]+$/ 6 4/' <<<"$c")" ;;
  esac
  c="$(sed -E -e "s#(^|[ ;])scripts/#\1$src/scripts/#g" -e "s#(^|[ ;=])configs/#\1$src/configs/#g" \
              -e "s#(^|[ ;])meshes/#\1$src/meshes/#g" -e "s#(^|[ ;=])build/#\1$SOFTDIFF_BUILD_DIR/#g" <<<"$c")"
  printf '%s\n' "$c"
}

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work"
total_start=$EPOCHREALTIME
elapsed() { awk -v a="$1" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.1f", b - a }'; }
for pass in $(seq "${TOUR_PASSES:-2}"); do
  while IFS= read -r command; do
    [[ -z "${command// }" ]] && continue
    short="$(shorten "$command")"
    start=$EPOCHREALTIME
    if ! bash -c "$short" >"$work/out.txt" 2>&1 </dev/null; then
      echo "run_tour: pass $pass: FAILED: $short" >&2
      cat "$work/out.txt" >&2
      exit 1
    fi
    printf 'pass %d  %6s s  %s\n' "$pass" "$(elapsed "$start")" "$command"
  done <<<"$tour"
done
echo "run_tour: the tour passed twice in $(elapsed "$total_start") s"
