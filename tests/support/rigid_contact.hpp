#pragma once
// Rigid bodies in contact, built in code (no scene file) for unit and validation tests:
// a Model with soft bodies (model_builder.hpp), rigid bodies added with their mass
// properties and tessellation, and contact detection laid out as build_model does
// (soft surfaces, rigid surfaces as pseudo-nodes, obstacles), with explicit pair rules.
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/rigid/rigid_body.hpp>
#include <support/contact.hpp>
#include <support/model_builder.hpp>

#include <string>
#include <utility>
#include <vector>

namespace softdiff::test {

// A free (or fixed) rigid body of uniform density with the given shape, initialized at `state`.
inline void add_rigid_body(Model& model, const std::string& name, const rigid::Shape& shape, double density,
                           const rigid::RigidState& state, double max_edge = 0.01,
                           rigid::Joint::Kind joint = rigid::Joint::Kind::free) {
  rigid::RigidBody b;
  b.name = name;
  b.shape = shape;
  const rigid::MassProperties p = rigid::mass_properties(shape, density);
  b.mass = p.mass;
  b.inertia = p.inertia;
  b.surface = rigid::tessellate(shape, p.centre, max_edge);
  b.joint.kind = joint;
  rigid::initialize(b, state);
  model.rigid.push_back(std::move(b));
  model.initial.rigid.push_back(model.rigid.back().reference);
}

inline rigid::Shape box_shape(const Vec3& half_extents) {
  rigid::Shape s;
  s.kind = rigid::Shape::Kind::box;
  s.half_extents = half_extents;
  return s;
}

// Pair rules by name: {a, b, mu}.
struct NamedPair {
  std::string a, b;
  double mu = 0;
};

// Contact on the model's soft and rigid bodies (add them first) and the obstacles, with
// exactly the pairs given.
inline void enable_rigid_contact(Model& model, std::vector<collision::Obstacle> obstacles,
                                 const std::vector<NamedPair>& pairs, double margin, const contact::NcpOptions& ncp) {
  auto& c = model.contact;
  c.enabled = true;
  c.ncp = ncp;
  auto& d = c.detection;
  d = {};
  d.margin = margin;
  for (const auto& b : model.fem.bodies) {
    d.surfaces.push_back(collision::make_surface(b.name, b.surface, b.node_begin));
    d.names.push_back(b.name);
  }
  contact::add_rigid_surfaces(model);
  for (auto& o : obstacles) d.names.push_back(o.name);
  d.obstacles = std::move(obstacles);
  auto index = [&](const std::string& n) {
    for (std::size_t i = 0; i < d.names.size(); ++i)
      if (d.names[i] == n) return static_cast<int>(i);
    return -1;
  };
  for (const auto& p : pairs) d.pairs.push_back({index(p.a), index(p.b), p.mu});
}

}  // namespace softdiff::test
