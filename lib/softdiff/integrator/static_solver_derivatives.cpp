// Derivatives of the static equilibrium: see static_solver_derivatives.hpp.
#include <softdiff/integrator/static_solver_derivatives.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/fem/fem_derivatives.hpp>
#include <softdiff/integrator/implicit_euler.hpp>

#include <string>
#include <variant>

namespace softdiff::integrator {

bool static_sensitivities(const Model& model, Data& data, const State& equilibrium, const StaticTheta& theta,
                          MatX& dx_dtheta) {
  const auto& fem = model.fem;
  SOFTDIFF_DEMAND(model.step.integrator == IntegratorKind::static_equilibrium, "static_sensitivities: not a static scene");
  SOFTDIFF_DEMAND(!model.contact.enabled, "static derivatives: contact is not differentiated in this version");
  for (const auto& b : fem.bodies)
    SOFTDIFF_DEMAND(!b.psd_projection, "static derivatives: psd_projection (body '" + b.name +
                                           "') is not differentiated in this version");
  for (const auto& a : model.actuation.actuators) {
    const auto* servo = std::get_if<actuation::Servo>(&a.kind);
    SOFTDIFF_DEMAND(std::holds_alternative<actuation::Cable>(a.kind) || (servo && !servo->is_rotation()),
                    "static derivatives: actuator '" + a.name + "' (" + a.kind_name() +
                        ") is not differentiated in this version (cables and translation servos are)");
  }
  const Eigen::Index n = 3L * fem.num_nodes, np = static_cast<Eigen::Index>(theta.parameters.size());
  const Eigen::Index na = theta.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
  const VecX& x = equilibrium.x;
  // The final load step's actuation values (values at pseudo-time 1; constants as given).
  if (!model.actuation.empty()) model.actuation.values(1.0, data.lambda_a);
  // J = K(x*) + sum_cables lambda d^2L/dx^2, projected.
  if (!fem::evaluate(fem, x, {false, true, true}, data.fem)) return false;
  double* A = data.A.valuePtr();
  for (long k = 0; k < data.A.nonZeros(); ++k) A[k] = data.fem.K_values[k];
  if (!model.actuation.empty()) model.actuation.add_stiffness(x, data.lambda_a, fem.pattern, A);
  for (int k : fem.pattern.fixed_offdiagonal) A[k] = 0;
  for (int k : fem.pattern.fixed_diagonal) A[k] = 1;
  data.factor_is_current = false;
  if (!factorize(model, data, 1).ok()) return false;

  dx_dtheta = MatX::Zero(n, np + na);
  VecX r(n), y(n), dKw(n);
  const VecX zero = VecX::Zero(n);
  for (Eigen::Index c = 0; c < np + na; ++c) {
    r.setZero();
    if (c < np) {
      const ParameterId& id = theta.parameters[static_cast<std::size_t>(c)];
      const auto& body = fem.bodies[static_cast<std::size_t>(id.body)];
      const Eigen::Index begin = 3L * body.node_begin, len = 3L * body.num_nodes;
      switch (id.kind) {
        case Parameter::young: r.segment(begin, len) = data.fem.f_int.segment(begin, len) / body.young; break;
        case Parameter::poisson:
          dKw.setZero();
          if (fem::add_elastic_parameter_derivative(fem, x, id.body, fem::ElasticParameter::poisson, zero, r, dKw) >= 0)
            return false;
          break;
        case Parameter::density: r.segment(begin, len) = fem.gravity_force.segment(begin, len) / body.density; break;
        case Parameter::rayleigh_mass:
        case Parameter::rayleigh_stiffness: continue;  // no effect on the equilibrium
        case Parameter::friction: return false;
      }
    } else {
      model.actuation.add_forces(x, VecX::Unit(static_cast<Eigen::Index>(model.actuation.actuators.size()), c - np), 1.0, r);
    }
    project(model, r);
    if (!data.solver->solve(r, y)) return false;
    project(model, y);
    dx_dtheta.col(c) = y;
  }
  return dx_dtheta.allFinite();
}

}  // namespace softdiff::integrator
