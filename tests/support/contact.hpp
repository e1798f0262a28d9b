#pragma once
// Contact in code (no scene file) for unit and validation tests: obstacles, pair
// rules like build_model's (every body vs every obstacle, optional self-contact).
// (contact_checks.hpp: an independent check of a step's contact solution.)
#include <softdiff/collision/detection.hpp>
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/contact/ncp.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <vector>

namespace softdiff::test {

inline collision::Obstacle plane(const Vec3& normal, double offset, const std::string& name = "floor") {
  collision::Obstacle o;
  o.name = name;
  o.kind = collision::ShapeKind::plane;
  o.normal = normal;
  o.offset = offset;
  collision::prepare(o);
  return o;
}

inline collision::Obstacle box(const Vec3& center, const Vec3& half_extents, const std::string& name) {
  collision::Obstacle o;
  o.name = name;
  o.kind = collision::ShapeKind::box;
  o.center = center;
  o.half_extents = half_extents;
  collision::prepare(o);
  return o;
}

struct ContactSpec {
  double mu = 0;
  double margin = 1e-3;
  bool self = false;
  contact::NcpOptions ncp;
};

inline void enable_contact(Model& model, std::vector<collision::Obstacle> obstacles, const ContactSpec& spec) {
  auto& c = model.contact;
  c.enabled = true;
  c.ncp = spec.ncp;
  auto& d = c.detection;
  d = {};
  d.margin = spec.margin;
  for (const auto& b : model.fem.bodies) {
    collision::BodySurface s = collision::make_surface(b.name, b.surface, b.node_begin);
    d.surfaces.push_back(std::move(s));
    d.names.push_back(b.name);
  }
  const int nb = static_cast<int>(model.fem.bodies.size());
  for (auto& o : obstacles) d.names.push_back(o.name);
  for (int b = 0; b < nb; ++b) {
    for (int o = 0; o < static_cast<int>(obstacles.size()); ++o) d.pairs.push_back({b, nb + o, spec.mu});
    if (spec.self) d.pairs.push_back({b, b, spec.mu});
  }
  d.obstacles = std::move(obstacles);
}

}  // namespace softdiff::test
