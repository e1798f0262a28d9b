#pragma once
// Plausibility of a built scene for a soft robot (docs/scene.md "Plausibility checks"):
// what is valid input but most likely a mistake, reported as warnings by io::build_model.
//   - size and mass: a body whose bounding box's largest extent is above kMaxExtent
//     (5 m) or below kMinExtent (1 mm), or whose mass is above kMaxMass (1000 kg). A
//     mesh in millimetres read as metres (no mesh_scale) gives a body 1000 times too
//     large and 10^9 times too heavy: the message then suggests `mesh_scale: 0.001`.
//     --strict (simulate, calibrate, control, info) makes these input errors.
//   - free fall: a dynamic scene with gravity whose body nothing holds: no fixed dof
//     along gravity, no contact pair with an obstacle or another body, no servo. It
//     falls for the whole run (a warning only: a drop can be intended).
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>

#include <string>
#include <vector>

namespace softdiff::io {

inline constexpr double kMaxExtent = 5.0;     // m
inline constexpr double kMinExtent = 1e-3;    // m
inline constexpr double kMaxMass = 1000.0;    // kg

struct BodySize {
  Vec3 extents = Vec3::Zero();  // rest bounding-box extents (m), world axes
  double mass = 0;              // kg
};

// Body b's rest bounding-box extents and mass.
BodySize body_size(const Model& model, int body);

// Appends to `implausible` the size/mass findings and to `warnings` the free-fall
// findings, each "FILE:LINE:COL: bodies[i]: body 'name' ...".
void check_plausibility(const SceneDesc& scene, const Model& model, std::vector<std::string>& implausible,
                        std::vector<std::string>& warnings);

}  // namespace softdiff::io
