// softdiff and Debian's libfcl must agree on the layout of FCL's types (the guard in
// lib/softdiff/collision/fcl.hpp checks it at compile time, cmake/FclAbi.cmake pins
// Eigen's alignment). This checks it at run time the way detection.cpp uses FCL:
// leaves whose boxes softdiff's code sets, read by libfcl's compiled broad phase.
// Built with -march=native on an AVX-512 CPU without the pin, libfcl read the boxes at
// the wrong offset and reported all 190 pairs of this row of 20 boxes (or crashed).
#include <softdiff/collision/fcl.hpp>

#include <gtest/gtest.h>

#include <memory>
#include <vector>

// A named namespace: this file is compiled in a unity batch with others.
namespace fcl_layout {

struct Leaf : fcl::CollisionObjectd {
  explicit Leaf(const std::shared_ptr<fcl::CollisionGeometryd>& g) : fcl::CollisionObjectd(g) {}
  void set_box(const fcl::Vector3d& lo, const fcl::Vector3d& hi) {
    aabb.min_ = lo;
    aabb.max_ = hi;
  }
};

bool count_pair(fcl::CollisionObjectd*, fcl::CollisionObjectd*, void* count) {
  ++*static_cast<int*>(count);
  return false;
}

TEST(FclLayout, LibfclReadsTheBoxesSoftdiffSets) {
  auto dummy = std::make_shared<fcl::Sphered>(0.0);
  std::vector<std::unique_ptr<Leaf>> leaves;
  std::vector<fcl::CollisionObjectd*> objects;
  const int n = 20;  // a row of unit boxes, each touching only its neighbours: n - 1 pairs
  for (int i = 0; i < n; ++i) {
    leaves.push_back(std::make_unique<Leaf>(dummy));
    leaves.back()->set_box(fcl::Vector3d(i, 0, 0), fcl::Vector3d(i + 1.0, 1, 1));
    objects.push_back(leaves.back().get());
  }
  fcl::DynamicAABBTreeCollisionManagerd manager;
  manager.registerObjects(objects);
  manager.setup();
  int pairs = 0;
  manager.collide(&pairs, count_pair);
  EXPECT_EQ(pairs, n - 1);
}

}  // namespace fcl_layout
