#pragma once
// Reading and changing a Model's differentiable parameters in place, with every
// derived quantity kept consistent (Lame constants; mass values, lumped masses, gravity
// forces and the total mass for density). Used by check-grad's finite differences and
// by calibration.
#include <softdiff/core/parameters.hpp>
#include <softdiff/model.hpp>

namespace softdiff::diff {

double get_parameter(const Model& model, const ParameterId& id);

// Sets the parameter. Throws std::invalid_argument for a value outside its range
// (young, density > 0; poisson in (-1, 0.5); Rayleigh factors and friction >= 0).
// Friction: the coefficient of pair rule id.body (the detector copies it into the
// contacts when a Data is built from the model).
void set_parameter(Model& model, const ParameterId& id, double value);

// Restores in `model` everything set_parameter(model, id, .) writes to its value in
// `base` (a model of the same scene: the same bodies, pattern and pair rules), e.g. for
// density the body's mass values, lumped masses and gravity forces and the total mass.
// Restoring every parameter of a list and then setting them in order gives the same
// model, bit for bit, as setting them in a copy of `base` (calibration's workspace:
// optim/calibration.hpp). No allocation.
void restore_parameter(Model& model, const Model& base, const ParameterId& id);

// Adds `offset` to actuator a's value at every time (its constant, or every point of
// its schedule): the "actuation" theta of a trajectory.
void offset_actuator(Model& model, int actuator, double offset);

}  // namespace softdiff::diff
