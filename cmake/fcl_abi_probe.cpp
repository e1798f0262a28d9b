// Configure-time probe (cmake/FclAbi.cmake): compiled with the flags Debian's libfcl
// was built with (the compiler's default target, no -march), it prints the layout of
// the FCL types that softdiff shares with libfcl, and Eigen's alignment bounds. The
// values become generated/softdiff/fcl_abi.hpp, which lib/softdiff/collision/fcl.hpp
// checks against the real build's flags.
#include <cstdio>
#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/geometry/shape/sphere.h>

int main() {
  std::printf("%d;%d;%zu;%zu;%zu;%zu;%zu;%zu;%zu;%zu;%zu;%zu\n", EIGEN_MAX_ALIGN_BYTES,
              EIGEN_MAX_STATIC_ALIGN_BYTES, sizeof(fcl::CollisionObjectd), alignof(fcl::CollisionObjectd),
              sizeof(fcl::Transform3d), alignof(fcl::Transform3d), sizeof(fcl::AABBd), alignof(fcl::AABBd),
              sizeof(fcl::Sphered), alignof(fcl::Sphered), sizeof(fcl::DynamicAABBTreeCollisionManagerd),
              alignof(fcl::DynamicAABBTreeCollisionManagerd));
  return 0;
}
