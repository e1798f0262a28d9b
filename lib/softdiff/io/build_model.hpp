#pragma once
// From a validated scene description to a Model: reads the meshes, applies the
// scene's transforms, resolves fixed sets, builds the FEM model (geometry, mass,
// pattern) and the initial state. Throws InputError (with the scene location) for
// problems that need the mesh to be seen: a physical group the mesh lacks, a box
// or node list that selects nothing, a node index out of range. With a report, adds
// the plausibility warnings of io/plausibility.hpp (errors with report->strict).
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>

#include <string>
#include <vector>

namespace softdiff::io {

struct BuildReport {
  // Input: implausible sizes and masses (io/plausibility.hpp) are input errors (the
  // first one thrown as InputError) instead of warnings (the commands' --strict).
  bool strict = false;
  std::vector<std::string> warnings;  // e.g. orphan nodes dropped, tets reoriented, a body
                                      // of implausible size or mass, a body held by nothing
};

Model build_model(const SceneDesc& scene, BuildReport* report = nullptr);

// Rotation R = Rz(c) Ry(b) Rx(a) for XYZ Euler angles (a, b, c) in degrees.
Mat3 rotation_from_euler_deg(const Vec3& angles_deg);

}  // namespace softdiff::io
