#!/usr/bin/env bash
# The installed package (docs/install.md; ctest -R install_external_project, label install):
#  1. `cmake --install` of this build into a temporary prefix (this project only, no sudo);
#  2. the installed tree refers to neither the source nor the build tree, every
#     #include <softdiff/...> of an installed header resolves inside it, and all the
#     installed headers compile in one translation unit with softdiff::softdiff's usage
#     requirements only (no CHOLMOD, FCL, HDF5 or yaml-cpp headers);
#  3. examples/external_project configured with -DCMAKE_PREFIX_PATH=<prefix> in a fresh
#     folder, built and run on the installed Finger scene: its output must equal, byte
#     for byte, the in-tree build of the same main.cpp on the source tree's scene (the
#     same library code on the same input; the scene path is not printed);
#  4. the installed CLI and the example load OpenBLAS-pthread, as the build tree's CLI
#     does (when the build pinned it);
#  5. a program compiled with another EIGEN_MAX_ALIGN_BYTES is refused at configure time
#     with a message naming it.
# Temporary folders are removed on exit; every path is absolute (any working folder).
# usage: external_project.sh CMAKE BUILD_DIR SOURCE_DIR CXX IN_TREE_EXAMPLE EIGEN_MAX_ALIGN_BYTES
set -euo pipefail
cmake=$1 build=$2 src=$3 cxx=$4 in_tree=$5 align=$6
tmp=$(mktemp -d "${TMPDIR:-/tmp}/softdiff_install.XXXXXX")
trap 'rm -rf "$tmp"' EXIT
prefix=$tmp/prefix
fail() { echo "FAIL: $*" >&2; exit 1; }
t0=$SECONDS

# 1. Install.
"$cmake" --install "$build" --prefix "$prefix" >"$tmp/install.log" || { cat "$tmp/install.log"; fail "cmake --install"; }
for f in lib/libsoftdiff.a bin/softdiff include/softdiff/model.hpp include/softdiff/version.hpp \
         lib/cmake/softdiff/softdiffConfig.cmake lib/cmake/softdiff/softdiffConfigVersion.cmake \
         lib/cmake/softdiff/softdiffTargets.cmake lib/cmake/softdiff/FindCHOLMOD.cmake \
         share/softdiff/configs/finger.yaml share/softdiff/meshes/finger.msh; do
  [[ -e $prefix/$f ]] || fail "not installed: $f"
done
[[ ! -e $prefix/include/softdiff/collision/fcl.hpp ]] || fail "the private header collision/fcl.hpp was installed"
echo "installed $(find "$prefix" -type f | wc -l) files ($(du -sh "$prefix" | cut -f1)) in $((SECONDS - t0)) s"

# 2. Relocatable and self-contained.
if grep -rlF -e "$src" -e "$build" "$prefix/lib/cmake" "$prefix/include"; then
  fail "the installed CMake files or headers above name the source or build tree"
fi
missing=0
while IFS= read -r inc; do
  [[ -e $prefix/include/$inc ]] || { echo "unresolved #include <$inc>" >&2; missing=1; }
done < <(grep -rhoE '^#include <softdiff/[^>]+>' "$prefix/include" | sed -E 's/#include <(.*)>/\1/' | sort -u)
((missing == 0)) || fail "installed headers include headers that are not installed"

# 3. The external project, against the installed tree only.
t1=$SECONDS
"$cmake" -S "$src/examples/external_project" -B "$tmp/example" -DCMAKE_PREFIX_PATH="$prefix" \
  -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_BUILD_TYPE=Release >"$tmp/configure.log" 2>&1 ||
  { cat "$tmp/configure.log"; fail "configuring examples/external_project"; }
"$cmake" --build "$tmp/example" -j2 >"$tmp/build.log" 2>&1 || { cat "$tmp/build.log"; fail "building examples/external_project"; }
echo "example configured and built in $((SECONDS - t1)) s"
installed=$tmp/example/softdiff_external_example
(cd "$tmp" && "$installed") >"$tmp/installed.out" || fail "the installed build's example exited $?"
"$in_tree" "$src/configs/finger.yaml" >"$tmp/in_tree.out" || fail "the in-tree example exited $?"
cat "$tmp/installed.out"
diff "$tmp/in_tree.out" "$tmp/installed.out" || fail "the installed build's output differs from the in-tree build's"
grep -q '^p = ' "$tmp/installed.out" && grep -q 'adjoint' "$tmp/installed.out" || fail "unexpected output"

# Every installed header compiles with softdiff::softdiff's usage requirements only (no
# CHOLMOD, FCL, HDF5 or yaml-cpp headers): one translation unit including them all.
mkdir -p "$tmp/headers"
(cd "$prefix/include" && find softdiff -name '*.hpp' | sort | sed 's/.*/#include <&>/') >"$tmp/headers/all.cpp"
cat >"$tmp/headers/CMakeLists.txt" <<'CMAKE'
cmake_minimum_required(VERSION 3.24)
project(softdiff_headers LANGUAGES CXX)
find_package(softdiff 0.1 REQUIRED)
add_library(all_headers OBJECT all.cpp)
target_link_libraries(all_headers PRIVATE softdiff::softdiff)
CMAKE
t1=$SECONDS
{ "$cmake" -S "$tmp/headers" -B "$tmp/headers/build" -DCMAKE_PREFIX_PATH="$prefix" -DCMAKE_CXX_COMPILER="$cxx" &&
  "$cmake" --build "$tmp/headers/build"; } >"$tmp/headers.log" 2>&1 ||
  { cat "$tmp/headers.log"; fail "the installed headers do not compile on their own"; }
echo "the $(wc -l <"$tmp/headers/all.cpp") installed headers compile together in $((SECONDS - t1)) s"

# 4. The BLAS pin.
pinned=$(readelf -d "$build/bin/softdiff" | grep -oE '/[^:]*/openblas-pthread' | head -1 || true)
if [[ -n $pinned ]]; then
  for exe in "$prefix/bin/softdiff" "$installed"; do
    blas=$(LD_TRACE_LOADED_OBJECTS=1 "$exe" | awk '$1 == "libblas.so.3" {print $3}')
    [[ $blas == "$pinned/libblas.so.3" ]] || fail "$exe loads libblas.so.3 from '$blas', not $pinned"
  done
  echo "installed CLI and example load $pinned/libblas.so.3"
else
  echo "the build pins no BLAS (SOFTDIFF_BLAS_DIR): not checked"
fi
"$prefix/bin/softdiff" info "$prefix/share/softdiff/configs/finger.yaml" >"$tmp/info.out" 2>&1 ||
  { cat "$tmp/info.out"; fail "the installed CLI cannot read the installed Finger scene"; }

# 5. Eigen's alignment ABI.
other=$((align == 16 ? 32 : 16))
if "$cmake" -S "$src/examples/external_project" -B "$tmp/example_abi" -DCMAKE_PREFIX_PATH="$prefix" \
     -DCMAKE_CXX_COMPILER="$cxx" -DCMAKE_CXX_FLAGS="-DEIGEN_MAX_ALIGN_BYTES=$other" >"$tmp/abi.log" 2>&1; then
  fail "configuring with -DEIGEN_MAX_ALIGN_BYTES=$other succeeded; softdiff was compiled with $align"
fi
tr -s ' \n' ' ' <"$tmp/abi.log" |
  grep -q "Eigen ABI mismatch: CMAKE_CXX_FLAGS defines EIGEN_MAX_ALIGN_BYTES=$other, but softdiff was compiled with EIGEN_MAX_ALIGN_BYTES=$align" ||
  { cat "$tmp/abi.log"; fail "no clear message for the Eigen alignment mismatch"; }
echo "configuring with -DEIGEN_MAX_ALIGN_BYTES=$other is refused"
echo "PASS in $((SECONDS - t0)) s"
