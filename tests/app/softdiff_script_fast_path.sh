#!/usr/bin/env bash
# scripts/softdiff's fast path (docs/cli.md "scripts/softdiff"): with a current build it
# runs the binary without scripts/setup (dpkg-query) or CMake; when a source is newer
# than the last build, or a file is added, it builds again, saying so on stderr.
# Hermetic: a copy of scripts/{softdiff,build,setup} in a temporary tree whose cmake,
# dpkg-query and clang++ are stubs on PATH that record their calls (cmake --build
# writes a fake bin/softdiff).
# Usage: softdiff_script_fast_path.sh SOURCE_DIR
set -euo pipefail
src="$1"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT
root="$tmp/repo"
mkdir -p "$root/scripts" "$root/lib/softdiff" "$root/app" "$root/cmake" "$tmp/stubs"
cp "$src/scripts/softdiff" "$src/scripts/build" "$src/scripts/setup" "$root/scripts/"
echo "project(fake)" >"$root/CMakeLists.txt"
echo "int f();" >"$root/lib/softdiff/f.cpp"
echo "int main();" >"$root/app/main.cpp"
echo "" >"$root/cmake/x.cmake"
calls="$tmp/calls"
cat >"$tmp/stubs/cmake" <<STUB
#!/usr/bin/env bash
echo "cmake \$*" >>"$calls"
if [[ "\$1" == -S ]]; then touch "\$4/CMakeCache.txt"; fi
if [[ "\$1" == --build ]]; then
  mkdir -p "\$2/bin"
  printf '#!/bin/sh\necho "fake softdiff \$*"\n' >"\$2/bin/softdiff"
  cp "\$2/bin/softdiff" "\$2/bin/softdiff_example_effector_gradient"
  chmod +x "\$2/bin/softdiff" "\$2/bin/softdiff_example_effector_gradient"
fi
STUB
cat >"$tmp/stubs/dpkg-query" <<STUB
#!/usr/bin/env bash
echo "dpkg-query \$*" >>"$calls"
printf 'install ok installed'
STUB
printf '#!/bin/sh\necho 14.0.6\n' >"$tmp/stubs/clang++"
chmod +x "$tmp/stubs/"*
export PATH="$tmp/stubs:$PATH"
unset SOFTDIFF_BUILD_DIR

fail() { echo "FAIL: $*" >&2; exit 1; }
run() {  # run ARGS...: scripts/softdiff with the stubs; stdout in $out, stderr in $err
  : >"$calls"
  out="$("$root/scripts/softdiff" "$@" 2>"$tmp/err")"
  err="$(cat "$tmp/err")"
}
built() { grep -q "^cmake --build" "$calls"; }
setup_ran() { grep -q "^dpkg-query" "$calls"; }

# 1. First use: setup, configure and build, with a message naming the log.
run --version
[[ "$out" == "fake softdiff --version" ]] || fail "first call printed '$out'"
built || fail "first call did not build"
setup_ran || fail "first call did not run scripts/setup"
[[ "$err" == *"softdiff: building"*"$root/build/build.log"* ]] || fail "first call's stderr: '$err'"
[[ -f "$root/build/.softdiff_stamp" ]] || fail "no stamp after a successful build"

# 2. Current build: neither setup nor CMake, nothing on stderr, same arguments.
run simulate "a b.yaml" --quiet
[[ "$out" == "fake softdiff simulate a b.yaml --quiet" ]] || fail "fast path printed '$out'"
[[ ! -s "$calls" ]] || fail "fast path ran: $(cat "$calls")"
[[ -z "$err" ]] || fail "fast path wrote to stderr: '$err'"

# 3. A source edited after the build: build again (setup included), then fast again.
sleep 1  # the stamp's and the edit's times differ on any file system
echo "int g();" >>"$root/lib/softdiff/f.cpp"
run --version
built || fail "no build after lib/softdiff/f.cpp changed"
setup_ran || fail "no setup before the rebuild"
run --version
[[ ! -s "$calls" ]] || fail "second call after the rebuild was not fast: $(cat "$calls")"

# 4. A file added to app/ (its folder's time changes), and CMakeLists.txt edited.
sleep 1
echo "" >"$root/app/new.cpp"
run --version
built || fail "no build after app/new.cpp was added"
sleep 1
echo "# edit" >>"$root/CMakeLists.txt"
run --version
built || fail "no build after CMakeLists.txt changed"

# 5. A missing example binary (a build of softdiff_cli alone) is built again.
rm "$root/build/bin/softdiff_example_effector_gradient"
run --version
built || fail "no build with the example binary missing"

# 6. A failed build: exit 1, no stamp update, the next call tries again.
sleep 1
echo "int h();" >>"$root/lib/softdiff/f.cpp"
cat >"$tmp/stubs/cmake" <<STUB
#!/usr/bin/env bash
echo "cmake \$*" >>"$calls"
echo "f.cpp:1: error: broken" 
exit 1
STUB
set +e
"$root/scripts/softdiff" --version >/dev/null 2>"$tmp/err"
code=$?
set -e
[[ $code -eq 1 ]] || fail "a failed build exited $code"
grep -q "build failed, full log in" "$tmp/err" || fail "a failed build's stderr: $(cat "$tmp/err")"
set +e
run --version
set -e
built || fail "no new build attempt after a failed build"
echo "scripts/softdiff fast path: 6 checks passed"
