#pragma once
// The SI units written as the `units` attribute of every output dataset
// (docs/output.md): "m", "m/s", "N", "s", "Pa", "1" for dimensionless values and
// indices. A dataset whose columns differ names one unit per column, comma-separated.
#include <softdiff/actuation/actuation_model.hpp>
#include <softdiff/core/parameters.hpp>

#include <string>
#include <vector>

namespace softdiff::io {

// young Pa, poisson 1, density kg/m^3, rayleigh_mass 1/s, rayleigh_stiffness s, friction 1.
std::string parameter_unit(Parameter p);
// The actuator's value: cable tension N, pressure Pa, servo force N (translation) or
// torque N m (rotation).
std::string actuator_value_unit(const actuation::ActuatorModel& a);
// Its measure: cable length m, closed-cavity volume m^3 ("" when it has none).
std::string actuator_measure_unit(const actuation::ActuatorModel& a);
// The unit of d x / d theta (x in m) for theta of unit `unit`: "m/Pa", "m" (for "1"),
// "1" (for "m"), "s" (for "m/s"), "m s" (for "1/s"), "m^4/kg", "1/N" (for "N m").
std::string position_per(const std::string& unit);
// One unit when every entry is the same, else the list comma-separated.
std::string column_units(const std::vector<std::string>& units);

}  // namespace softdiff::io
