#pragma once
// The scenes of the calibration and control tests with rigidified parts (issue 21;
// docs/method.md "Calibration", "Control", "Rigidified parts"): the shipped clamped beam
// (meshes/beam.msh, 0.2 x 0.02 x 0.02 m, E = 1 MPa) with its last quarter (x >= 0.15)
// rigidified, either free (it falls under gravity with the bending beam) or attached to a
// torque servo about the beam's axis at the tip (it turns the part, which twists the
// beam). Implicit Euler, one Newton iteration (the reduced step; its derivative:
// integrator/rigidify_derivatives.hpp).
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>
#include <support/cli.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace softdiff::test::rigidify_optim {

namespace fs = std::filesystem;

inline std::string beam_with_tip(bool servo, long steps) {
  std::string s = "softdiff: 1\n"
                  "simulation: {dt: 0.01, steps: " + std::to_string(steps) + "}\n"
                  "bodies:\n"
                  "  - name: beam\n"
                  "    mesh: " + (fs::path(SOFTDIFF_SOURCE_DIR) / "meshes/beam.msh").string() + "\n"
                  "    material: {young: 1.0e6, poisson: 0.45, density: 1070}\n"
                  "    damping: {rayleigh_mass: 0.5, rayleigh_stiffness: 0.002}\n"
                  "    fixed: [{group: clamp}]\n";
  if (servo)
    s += "    rigidify: [{box: [0.15, -1, -1, 1, 1, 1], attach: turn}]\n"
         "    actuators:\n"
         "      - {name: turn, type: servo, nodes: {group: tip}, axis: [1, 0, 0], center: [0.2, 0.01, 0.01], "
         "force: 0.001, limits: [-0.01, 0.01]}\n"
         "    effectors:\n"
         "      - {name: corner, point: [0.2, 0.02, 0.02]}\n";
  else
    s += "    rigidify: [{box: [0.15, -1, -1, 1, 1, 1], attach: free}]\n";
  return s;
}

// The model of beam_with_tip, through the scene file (written under the tests' data dir).
inline Model load_beam_with_tip(const std::string& name, bool servo, long steps,
                                const std::vector<std::string>& overrides = {}) {
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "rigidify_optim" / name;
  fs::create_directories(dir);
  write_text(dir / "scene.yaml", beam_with_tip(servo, steps));
  return io::build_model(io::load_scene(dir / "scene.yaml", overrides));
}

// The nodes of the model's first part (x >= 0.15 at rest).
inline std::vector<int> part_nodes(const Model& model) { return model.rigidify.parts.front().nodes; }

}  // namespace softdiff::test::rigidify_optim
