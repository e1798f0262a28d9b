#include <softdiff/io/plausibility.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace softdiff::io {

BodySize body_size(const Model& model, int body) {
  const auto& b = model.fem.bodies[static_cast<std::size_t>(body)];
  BodySize s;
  if (b.num_nodes == 0) return s;
  const auto X = model.fem.X.middleCols(b.node_begin, b.num_nodes);
  s.extents = X.rowwise().maxCoeff() - X.rowwise().minCoeff();
  s.mass = model.fem.mass_diagonal.segment(3 * b.node_begin, 3 * b.num_nodes).sum() / 3;
  return s;
}

namespace {

std::string body_label(const BodyDesc& bd, std::size_t i) {
  Where w = bd.where;
  w.path = "bodies[" + std::to_string(i) + "]";
  return w.str() + ": body '" + bd.name + "'";
}

// "200 x 20 x 20 m (bounding box) and 85600 kg"
std::string describe(const BodySize& s) {
  char buf[160];
  std::snprintf(buf, sizeof buf, "%.4g x %.4g x %.4g m (bounding box) and %.4g kg", s.extents.x(), s.extents.y(),
                s.extents.z(), s.mass);
  return buf;
}

}  // namespace

void check_plausibility(const SceneDesc& scene, const Model& model, std::vector<std::string>& implausible,
                        std::vector<std::string>& warnings) {
  const auto& fem = model.fem;
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  const Vec3 g = model.step.gravity;
  for (std::size_t i = 0; i < scene.bodies.size() && i < fem.bodies.size(); ++i) {
    const BodyDesc& bd = scene.bodies[i];
    const auto& b = fem.bodies[i];
    const BodySize s = body_size(model, static_cast<int>(i));
    const double largest = s.extents.maxCoeff();
    std::string why;
    if (largest > kMaxExtent) why = "its largest extent is above 5 m";
    else if (largest < kMinExtent) why = "its largest extent is below 1 mm";
    if (s.mass > kMaxMass) why += std::string(why.empty() ? "" : " and ") + "its mass is above 1000 kg";
    if (!why.empty()) {
      char scale[48];
      std::snprintf(scale, sizeof scale, "%g", bd.mesh_scale);
      std::string hint;
      if (largest > kMaxExtent && largest * 1e-3 <= kMaxExtent && largest * 1e-3 >= kMinExtent)
        hint = bd.mesh_scale == 1.0
                   ? "; the mesh looks like millimetres (coordinates are metres): set mesh_scale: 0.001"
                   : std::string("; the mesh looks like millimetres after mesh_scale: ") + scale +
                         " (coordinates are metres): scale it by 0.001 more";
      else if (largest < kMinExtent && bd.mesh_scale != 1.0)
        hint = std::string("; coordinates are metres after mesh_scale: ") + scale + ": is the mesh already in metres?";
      else if (s.mass > kMaxMass && largest <= kMaxExtent)
        hint = "; check the density (kg/m^3)";
      else
        hint = "; check the mesh's units (coordinates are metres after mesh_scale) and the density (kg/m^3)";
      implausible.push_back(body_label(bd, i) + " is " + describe(s) + ": implausible for a soft robot (" + why + ")" +
                            hint);
    }
    // Free fall (dynamic scenes with gravity).
    if (is_static || g.squaredNorm() == 0) continue;
    bool held = false;
    for (int k = 3 * b.node_begin; k < 3 * (b.node_begin + b.num_nodes) && !held; ++k)
      held = fem.fixed[static_cast<std::size_t>(k)] && g[k % 3] != 0;
    if (model.contact.enabled)
      for (const auto& p : model.contact.detection.pairs)
        held = held || (p.a != p.b && (p.a == static_cast<int>(i) || p.b == static_cast<int>(i)));
    for (const auto& a : model.actuation.actuators)
      held = held || (a.body == static_cast<int>(i) && std::holds_alternative<actuation::Servo>(a.kind));
    if (!held) {
      char buf[64];
      std::snprintf(buf, sizeof buf, "%g m/s^2", g.norm());
      warnings.push_back(body_label(bd, i) + " is held by nothing (no fixed node along gravity, no contact with " +
                         "an obstacle or another body, no servo): it falls freely under gravity (" + buf +
                         ") for the whole run; add `fixed`, enable `contact` with an obstacle, or set gravity: "
                         "[0, 0, 0] if this is intended");
    }
  }
}

}  // namespace softdiff::io
