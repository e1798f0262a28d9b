#include <softdiff/diff/parameters.hpp>

#include <softdiff/core/assert.hpp>

#include <stdexcept>
#include <string>

namespace softdiff::diff {

namespace {

fem::BodyModel& body_of(Model& model, const ParameterId& id) {
  SOFTDIFF_DEMAND(id.body >= 0 && id.body < static_cast<int>(model.fem.bodies.size()), "parameter: no such body");
  return model.fem.bodies[static_cast<std::size_t>(id.body)];
}

}  // namespace

double get_parameter(const Model& model, const ParameterId& id) {
  if (id.kind == Parameter::friction) {
    SOFTDIFF_DEMAND(id.body >= 0 && id.body < static_cast<int>(model.contact.detection.pairs.size()),
                    "parameter friction: no such pair rule");
    return model.contact.detection.pairs[static_cast<std::size_t>(id.body)].mu;
  }
  SOFTDIFF_DEMAND(id.body >= 0 && id.body < static_cast<int>(model.fem.bodies.size()), "parameter: no such body");
  const auto& b = model.fem.bodies[static_cast<std::size_t>(id.body)];
  switch (id.kind) {
    case Parameter::young: return b.young;
    case Parameter::poisson: return b.poisson;
    case Parameter::density: return b.density;
    case Parameter::rayleigh_mass: return b.rayleigh_mass;
    case Parameter::rayleigh_stiffness: return b.rayleigh_stiffness;
    case Parameter::friction: break;
  }
  throw std::invalid_argument("unknown parameter");
}

void set_parameter(Model& model, const ParameterId& id, double value) {
  if (id.kind == Parameter::friction) {
    SOFTDIFF_DEMAND(id.body >= 0 && id.body < static_cast<int>(model.contact.detection.pairs.size()),
                    "parameter friction: no such pair rule");
    if (!(value >= 0)) throw std::invalid_argument("friction must be >= 0, got " + std::to_string(value));
    model.contact.detection.pairs[static_cast<std::size_t>(id.body)].mu = value;
    return;
  }
  auto& b = body_of(model, id);
  const std::string name(parameter_name(id.kind));
  auto demand = [&](bool ok, const char* range) {
    if (!ok) throw std::invalid_argument(name + " of body '" + b.name + "' must be " + range + ", got " + std::to_string(value));
  };
  switch (id.kind) {
    case Parameter::young:
      demand(value > 0, "> 0");
      b.young = value;
      b.lame = material::lame_from_young_poisson(b.young, b.poisson);
      return;
    case Parameter::poisson:
      demand(value > -1 && value < 0.5, "in (-1, 0.5)");
      b.poisson = value;
      b.lame = material::lame_from_young_poisson(b.young, b.poisson);
      return;
    case Parameter::density: {
      demand(value > 0, "> 0");
      // M and P = M g are proportional to the density, body by body.
      const double ratio = value / b.density;
      auto& fem = model.fem;
      for (int k = b.value_begin; k < b.value_end; ++k) fem.mass_values[k] *= ratio;
      const Eigen::Index begin = 3L * b.node_begin, len = 3L * b.num_nodes;
      fem.mass_diagonal.segment(begin, len) *= ratio;
      fem.gravity_force.segment(begin, len) *= ratio;
      fem.total_mass += (ratio - 1) * fem.mass_diagonal.segment(begin, len).sum() / ratio / 3;
      b.density = value;
      return;
    }
    case Parameter::rayleigh_mass:
      demand(value >= 0, ">= 0");
      b.rayleigh_mass = value;
      return;
    case Parameter::rayleigh_stiffness:
      demand(value >= 0, ">= 0");
      b.rayleigh_stiffness = value;
      return;
    case Parameter::friction: break;
  }
}

void restore_parameter(Model& model, const Model& base, const ParameterId& id) {
  if (id.kind == Parameter::friction) {
    SOFTDIFF_DEMAND(id.body >= 0 && id.body < static_cast<int>(model.contact.detection.pairs.size()) &&
                        model.contact.detection.pairs.size() == base.contact.detection.pairs.size(),
                    "parameter friction: no such pair rule");
    const auto i = static_cast<std::size_t>(id.body);
    model.contact.detection.pairs[i].mu = base.contact.detection.pairs[i].mu;
    return;
  }
  auto& b = body_of(model, id);
  SOFTDIFF_DEMAND(model.fem.bodies.size() == base.fem.bodies.size(), "restore_parameter: not the same scene");
  const auto& o = base.fem.bodies[static_cast<std::size_t>(id.body)];
  switch (id.kind) {
    case Parameter::young:
    case Parameter::poisson:
      b.young = o.young;
      b.poisson = o.poisson;
      b.lame = o.lame;
      return;
    case Parameter::density: {
      auto& fem = model.fem;
      const auto& bf = base.fem;
      SOFTDIFF_DEMAND(fem.mass_values.size() == bf.mass_values.size() && fem.mass_diagonal.size() == bf.mass_diagonal.size(),
                      "restore_parameter: not the same scene");
      for (int k = b.value_begin; k < b.value_end; ++k) fem.mass_values[k] = bf.mass_values[k];
      const Eigen::Index begin = 3L * b.node_begin, len = 3L * b.num_nodes;
      fem.mass_diagonal.segment(begin, len) = bf.mass_diagonal.segment(begin, len);
      fem.gravity_force.segment(begin, len) = bf.gravity_force.segment(begin, len);
      fem.total_mass = bf.total_mass;
      b.density = o.density;
      return;
    }
    case Parameter::rayleigh_mass: b.rayleigh_mass = o.rayleigh_mass; return;
    case Parameter::rayleigh_stiffness: b.rayleigh_stiffness = o.rayleigh_stiffness; return;
    case Parameter::friction: break;
  }
}

void offset_actuator(Model& model, int actuator, double offset) {
  SOFTDIFF_DEMAND(actuator >= 0 && actuator < static_cast<int>(model.actuation.actuators.size()),
                  "offset_actuator: no such actuator");
  auto& v = model.actuation.actuators[static_cast<std::size_t>(actuator)].value;
  v.constant += offset;
  for (auto& p : v.points) p[1] += offset;
}

}  // namespace softdiff::diff
