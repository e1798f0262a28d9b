#pragma once
// The differentiable parameters (method.md "Derivatives"), by name, so that "with
// respect to what" is data: a list of ParameterId selects the columns of a Jacobian
// (or the entries of a gradient) in that order.
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace softdiff {

enum class Parameter { young, poisson, density, rayleigh_mass, rayleigh_stiffness, friction };

constexpr std::string_view parameter_name(Parameter p) {
  switch (p) {
    case Parameter::young: return "young";
    case Parameter::poisson: return "poisson";
    case Parameter::density: return "density";
    case Parameter::rayleigh_mass: return "rayleigh_mass";
    case Parameter::rayleigh_stiffness: return "rayleigh_stiffness";
    case Parameter::friction: return "friction";
  }
  return "?";
}

inline std::optional<Parameter> parse_parameter(std::string_view name) {
  for (Parameter p : {Parameter::young, Parameter::poisson, Parameter::density, Parameter::rayleigh_mass,
                      Parameter::rayleigh_stiffness, Parameter::friction})
    if (parameter_name(p) == name) return p;
  return std::nullopt;
}

// A parameter of one body (material and damping parameters are per body). For
// friction, `body` is the index of the contact pair rule (model.contact.detection.pairs)
// whose coefficient it is.
struct ParameterId {
  Parameter kind = Parameter::young;
  int body = 0;
  bool operator==(const ParameterId&) const = default;
};

}  // namespace softdiff
