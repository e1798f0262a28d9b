# Eigen's alignment ABI between softdiff and Debian's libfcl.
#
# FCL's public types hold fixed-size Eigen members (fcl::CollisionObjectd holds a
# Transform3d, i.e. a Matrix4d). Their alignment, and so the layout of every FCL
# object, follows EIGEN_MAX_STATIC_ALIGN_BYTES, which Eigen derives from the
# instruction set: 16 bytes for baseline x86-64 (how Debian compiles libfcl), 32 with
# AVX, 64 with AVX-512. Code compiled with -march=native on an AVX-512 CPU therefore
# saw a 256-byte CollisionObjectd where libfcl sees 224 bytes, and libfcl read the
# broad phase's boxes at the wrong offsets (SIGSEGV/SIGBUS in every contact scene).
#
# This module
#  1. compiles and runs a probe with the flags libfcl was built with
#     (SOFTDIFF_FCL_ABI_FLAGS: empty = the compiler's default target) and records the
#     FCL types' layout and Eigen's alignment bounds in generated/softdiff/fcl_abi.hpp;
#  2. sets SOFTDIFF_EIGEN_MAX_ALIGN_BYTES to libfcl's bound. CMakeLists.txt makes it a
#     PUBLIC definition of softdiff (EIGEN_MAX_ALIGN_BYTES), so that softdiff, its
#     tests and any program linking softdiff lay out Eigen types as libfcl does,
#     whatever -m flags they are compiled with (Eigen documents this use: "compile AVX
#     code and enforce ABI compatibility with existing SSE code").
# lib/softdiff/collision/fcl.hpp, the only header that includes FCL, static_asserts
# that the layouts it sees equal the probe's, so a mismatch fails the build.
set(SOFTDIFF_FCL_ABI_FLAGS "" CACHE STRING
    "Compiler flags Debian's libfcl was built with (empty: the compiler's default target)")

try_run(_fcl_abi_run _fcl_abi_compile
  ${CMAKE_BINARY_DIR}/fcl_abi_probe ${CMAKE_CURRENT_LIST_DIR}/fcl_abi_probe.cpp
  CMAKE_FLAGS "-DCMAKE_CXX_FLAGS=${SOFTDIFF_FCL_ABI_FLAGS}"
              "-DINCLUDE_DIRECTORIES=${EIGEN3_INCLUDE_DIR}"
  CXX_STANDARD 20
  COMPILE_OUTPUT_VARIABLE _fcl_abi_compile_out
  RUN_OUTPUT_VARIABLE _fcl_abi_out)
if(NOT _fcl_abi_compile OR NOT _fcl_abi_run EQUAL 0)
  message(FATAL_ERROR "softdiff: could not probe FCL's type layout:\n${_fcl_abi_compile_out}\n${_fcl_abi_out}")
endif()
string(STRIP "${_fcl_abi_out}" _fcl_abi_out)
list(GET _fcl_abi_out 0 SOFTDIFF_FCL_EIGEN_MAX_ALIGN_BYTES)
list(GET _fcl_abi_out 1 SOFTDIFF_FCL_EIGEN_MAX_STATIC_ALIGN_BYTES)
list(GET _fcl_abi_out 2 SOFTDIFF_FCL_SIZEOF_COLLISION_OBJECT)
list(GET _fcl_abi_out 3 SOFTDIFF_FCL_ALIGNOF_COLLISION_OBJECT)
list(GET _fcl_abi_out 4 SOFTDIFF_FCL_SIZEOF_TRANSFORM)
list(GET _fcl_abi_out 5 SOFTDIFF_FCL_ALIGNOF_TRANSFORM)
list(GET _fcl_abi_out 6 SOFTDIFF_FCL_SIZEOF_AABB)
list(GET _fcl_abi_out 7 SOFTDIFF_FCL_ALIGNOF_AABB)
list(GET _fcl_abi_out 8 SOFTDIFF_FCL_SIZEOF_SPHERE)
list(GET _fcl_abi_out 9 SOFTDIFF_FCL_ALIGNOF_SPHERE)
list(GET _fcl_abi_out 10 SOFTDIFF_FCL_SIZEOF_TREE_MANAGER)
list(GET _fcl_abi_out 11 SOFTDIFF_FCL_ALIGNOF_TREE_MANAGER)
set(SOFTDIFF_EIGEN_MAX_ALIGN_BYTES ${SOFTDIFF_FCL_EIGEN_MAX_ALIGN_BYTES})
message(STATUS "softdiff: libfcl's Eigen alignment is ${SOFTDIFF_FCL_EIGEN_MAX_ALIGN_BYTES} bytes "
               "(CollisionObjectd: ${SOFTDIFF_FCL_SIZEOF_COLLISION_OBJECT} bytes); softdiff uses the same")
configure_file(${CMAKE_CURRENT_LIST_DIR}/fcl_abi.hpp.in
               ${CMAKE_BINARY_DIR}/generated/softdiff/fcl_abi.hpp @ONLY)
