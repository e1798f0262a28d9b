// SI units of the output datasets: see units.hpp.
#include <softdiff/io/units.hpp>

#include <softdiff/core/assert.hpp>

#include <variant>

namespace softdiff::io {

std::string parameter_unit(Parameter p) {
  switch (p) {
    case Parameter::young: return "Pa";
    case Parameter::poisson: return "1";
    case Parameter::density: return "kg/m^3";
    case Parameter::rayleigh_mass: return "1/s";
    case Parameter::rayleigh_stiffness: return "s";
    case Parameter::friction: return "1";
  }
  return "1";
}

std::string actuator_value_unit(const actuation::ActuatorModel& a) {
  if (std::holds_alternative<actuation::Cavity>(a.kind)) return "Pa";
  if (const auto* servo = std::get_if<actuation::Servo>(&a.kind); servo && servo->is_rotation()) return "N m";
  return "N";
}

std::string actuator_measure_unit(const actuation::ActuatorModel& a) {
  if (!a.has_measure()) return "";
  return std::holds_alternative<actuation::Cable>(a.kind) ? "m" : "m^3";
}

std::string position_per(const std::string& unit) {
  if (unit == "1") return "m";
  if (unit == "m") return "1";
  if (unit == "m/s") return "s";
  if (unit == "1/s") return "m s";
  if (unit == "s") return "m/s";
  if (unit == "kg/m^3") return "m^4/kg";
  if (unit == "N m") return "1/N";
  SOFTDIFF_DEMAND(unit == "Pa" || unit == "N", "no rule for m per '" + unit + "'");
  return "m/" + unit;
}

std::string column_units(const std::vector<std::string>& units) {
  std::string out;
  bool same = true;
  for (const std::string& u : units) {
    same = same && u == units.front();
    out += (out.empty() ? "" : ",") + u;
  }
  if (units.empty()) return "1";
  return same ? units.front() : out;
}

}  // namespace softdiff::io
