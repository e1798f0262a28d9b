#!/usr/bin/env bash
# The FCL layout guard (lib/softdiff/collision/fcl.hpp, cmake/FclAbi.cmake), tested the
# way it protects the build: compile a translation unit that includes FCL through the
# guard with the instruction sets of baseline, AVX2 and AVX-512 CPUs.
#  - with softdiff's pin (-DEIGEN_MAX_ALIGN_BYTES=<libfcl's>) every one must compile;
#  - without it, AVX2 and AVX-512 change Eigen's alignment, and the guard must stop the
#    compilation with its message (an AVX-512 build without the pin crashed in libfcl);
#  - no source includes FCL except through the guard;
#  - HDF5 appears only in lib/softdiff/io/*.cpp (not in app/ nor in any header).
# Usage: fcl_abi_guard.sh CXX SOURCE_DIR GENERATED_DIR EIGEN_INCLUDE_DIR ALIGN
set -uo pipefail
cxx=$1 src=$2 gen=$3 eigen=$4 align=$5
failures=0
check() {  # check EXPECT(pass|fail) LABEL FLAGS...
  local expect=$1 label=$2; shift 2
  local out
  out=$("$cxx" -std=c++20 -fsyntax-only -I"$src/lib" -I"$gen" -isystem "$eigen" "$@" \
        "$src/tests/collision/fcl_abi_check.cpp" 2>&1)
  local rc=$?
  if [[ $expect == pass && $rc -ne 0 ]]; then
    echo "FAIL: $label: expected to compile, got:"; echo "$out" | head -20; failures=$((failures + 1))
  elif [[ $expect == fail && ( $rc -eq 0 || $out != *"FCL type layout differs"* ) ]]; then
    echo "FAIL: $label: expected the layout guard to stop the build (rc $rc):"; echo "$out" | head -20
    failures=$((failures + 1))
  else
    echo "ok: $label ($expect)"
  fi
}
pin=(-DEIGEN_MAX_ALIGN_BYTES="$align")
check pass "baseline x86-64, pinned" "${pin[@]}"
check pass "baseline x86-64, unpinned" -march=x86-64
check pass "AVX2, pinned" -march=haswell "${pin[@]}"
check pass "-mavx512f, pinned" -mavx512f -mfma "${pin[@]}"
check pass "AVX-512 (skylake-avx512), pinned" -march=skylake-avx512 "${pin[@]}"
check fail "AVX2, unpinned" -march=haswell
check fail "-mavx512f, unpinned" -mavx512f -mfma
check fail "AVX-512 (skylake-avx512), unpinned" -march=skylake-avx512

# FCL only through the guard (fcl/config.h holds version macros, no Eigen types).
bad=$(grep -rnE '#include *[<"]fcl/' "$src/lib" "$src/app" "$src/tests" --include='*.cpp' --include='*.hpp' |
      grep -v '/lib/softdiff/collision/fcl.hpp:' | grep -v 'fcl/config.h' || true)
if [[ -n $bad ]]; then
  echo "FAIL: FCL included without the layout guard (include softdiff/collision/fcl.hpp instead):"
  echo "$bad"; failures=$((failures + 1))
else
  echo "ok: FCL is included only through softdiff/collision/fcl.hpp"
fi
# HDF5 only in lib/softdiff/io/*.cpp (STYLE.md section 1: the stage that wraps it; its
# headers, and app/, see std types only): no <hdf5.h>, no H5* call or type, no hid_t,
# herr_t or hsize_t anywhere else in lib/ or app/ (comments aside). tests/ may read the
# files with the C API (tests/support/h5.hpp).
bad=$(find "$src/lib" "$src/app" -type f \( -name '*.cpp' -o -name '*.hpp' \) | grep -vE '/lib/softdiff/io/[^/]+\.cpp$' |
      sort | xargs awk '{
        code = $0; sub(/\/\/.*/, "", code)
        if (code ~ /#include *[<"]([A-Za-z0-9_]+\/)*hdf5\.h[>"]/ ||
            code ~ /(^|[^A-Za-z0-9_])(H5[A-Z][A-Za-z0-9_]*|hid_t|herr_t|hsize_t)([^A-Za-z0-9_]|$)/)
          print FILENAME ":" FNR ": " $0
      }' || true)
if [[ -n $bad ]]; then
  echo "FAIL: HDF5 used outside lib/softdiff/io/*.cpp (use io/hdf5_reader.hpp, io/hdf5_table.hpp, io/hdf5_writer.hpp):"
  echo "$bad"; failures=$((failures + 1))
else
  echo "ok: HDF5 is used only in lib/softdiff/io/*.cpp"
fi
echo "fcl_abi_guard: $failures check(s) failed"
exit $((failures > 0))
