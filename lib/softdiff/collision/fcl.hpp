#pragma once
// The one place softdiff includes FCL (a private header of collision/: public headers
// expose only Eigen and std types). It checks, at compile time, that this translation
// unit lays out FCL's types exactly as Debian's libfcl does.
//
// Why: FCL's types hold fixed-size Eigen members, whose alignment follows the
// instruction set the code is compiled for (16 bytes at baseline x86-64, 32 with AVX,
// 64 with AVX-512). libfcl is compiled for baseline x86-64. softdiff pins Eigen's
// alignment bound to libfcl's (EIGEN_MAX_ALIGN_BYTES, a PUBLIC definition of the
// softdiff target, from cmake/FclAbi.cmake), so any -m flags keep the layout. Without
// that pin, an -march=native build on an AVX-512 CPU saw a 256-byte CollisionObjectd
// where libfcl sees 224 bytes, and every contact scene crashed inside libfcl.
//
// Only fixed-size Eigen objects cross into libfcl here (boxes, transforms): heap
// storage of dynamic-size Eigen objects is allocated with Eigen's default alignment,
// which may differ between libfcl and softdiff, so no dynamic-size Eigen object may be
// created on one side and freed on the other. softdiff passes FCL only
// CollisionObjectd/Sphered objects and raw pointers.
#include <softdiff/fcl_abi.hpp>  // generated: libfcl's layouts, measured at configure time

#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/geometry/shape/sphere.h>

#define SOFTDIFF_FCL_ABI_MESSAGE                                                              \
  "FCL type layout differs from Debian's libfcl: Eigen's alignment in this translation unit " \
  "is not libfcl's. Compile with EIGEN_MAX_ALIGN_BYTES=SOFTDIFF_FCL_EIGEN_MAX_ALIGN_BYTES "     \
  "(link the softdiff target, which defines it) - see cmake/FclAbi.cmake"

static_assert(EIGEN_MAX_ALIGN_BYTES == SOFTDIFF_FCL_EIGEN_MAX_ALIGN_BYTES, SOFTDIFF_FCL_ABI_MESSAGE);
static_assert(EIGEN_MAX_STATIC_ALIGN_BYTES == SOFTDIFF_FCL_EIGEN_MAX_STATIC_ALIGN_BYTES, SOFTDIFF_FCL_ABI_MESSAGE);
static_assert(sizeof(fcl::CollisionObjectd) == SOFTDIFF_FCL_SIZEOF_COLLISION_OBJECT &&
                  alignof(fcl::CollisionObjectd) == SOFTDIFF_FCL_ALIGNOF_COLLISION_OBJECT,
              SOFTDIFF_FCL_ABI_MESSAGE);
static_assert(sizeof(fcl::Transform3d) == SOFTDIFF_FCL_SIZEOF_TRANSFORM &&
                  alignof(fcl::Transform3d) == SOFTDIFF_FCL_ALIGNOF_TRANSFORM,
              SOFTDIFF_FCL_ABI_MESSAGE);
static_assert(sizeof(fcl::AABBd) == SOFTDIFF_FCL_SIZEOF_AABB && alignof(fcl::AABBd) == SOFTDIFF_FCL_ALIGNOF_AABB,
              SOFTDIFF_FCL_ABI_MESSAGE);
static_assert(sizeof(fcl::Sphered) == SOFTDIFF_FCL_SIZEOF_SPHERE && alignof(fcl::Sphered) == SOFTDIFF_FCL_ALIGNOF_SPHERE,
              SOFTDIFF_FCL_ABI_MESSAGE);
static_assert(sizeof(fcl::DynamicAABBTreeCollisionManagerd) == SOFTDIFF_FCL_SIZEOF_TREE_MANAGER &&
                  alignof(fcl::DynamicAABBTreeCollisionManagerd) == SOFTDIFF_FCL_ALIGNOF_TREE_MANAGER,
              SOFTDIFF_FCL_ABI_MESSAGE);
