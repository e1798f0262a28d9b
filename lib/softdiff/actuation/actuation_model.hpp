#pragma once
// The actuation part of a Model: every actuator of every body with its value over
// time, and the effectors. Built by io::build_model. The actuation force on the
// nodes is +h H_a(x)^T lambda_a (method.md), evaluated at the step's x_i.
#include <softdiff/actuation/cable.hpp>
#include <softdiff/actuation/effector.hpp>
#include <softdiff/actuation/pressure.hpp>
#include <softdiff/actuation/servo.hpp>
#include <softdiff/fem/fem_model.hpp>

#include <array>
#include <string>
#include <variant>
#include <vector>

namespace softdiff::actuation {

// lambda_a(t): a constant, or a piecewise-linear schedule [(t0, v0), (t1, v1), ...]
// (times increasing), held constant before t0 and after the last time.
struct Schedule {
  double constant = 0;
  std::vector<std::array<double, 2>> points;
  double at(double t) const;
};

struct ActuatorModel {
  std::string name;
  int body = 0;
  std::variant<Cavity, Cable, Servo> kind;  // Cavity first: default-constructible
  Schedule value;
  bool has_limits = false;
  std::array<double, 2> limits{0, 0};

  const char* kind_name() const;
  // f += scale * lambda * H_a(x)^T
  void add_force(const VecX& x, double lambda, double scale, VecX& f) const;
  // out += d(H_a^T lambda)/dx . dx
  void add_force_derivative(const VecX& x, double lambda, const VecX& dx, VecX& out) const;
  // out += (d(H_a^T lambda)/dx)^T y
  void add_force_derivative_transpose(const VecX& x, double lambda, const VecX& y, VecX& out) const;
  // The measured quantity written to the output: cable length, closed-cavity volume;
  // NaN for others.
  double measure(const VecX& x) const;
  bool has_measure() const;
  const char* measure_name() const;  // "length", "volume" or ""
};

struct EffectorModel {
  std::string name;
  int body = 0;
  Effector effector;
};

struct ActuationModel {
  std::vector<ActuatorModel> actuators;
  std::vector<EffectorModel> effectors;

  bool empty() const { return actuators.empty(); }
  // lambda_a(t) for every actuator.
  void values(double t, VecX& lambda) const;
  // True if every actuator's force derives from a potential: cables (lambda L),
  // closed cavities (-p V), translation servos (-lambda d . mean of the nodes).
  bool conservative() const;
  // The actuators' potential energy U(x) with f = -dU/dx = sum_a lambda_a H_a^T
  // (only meaningful when conservative()).
  double potential(const VecX& x, const VecX& lambda) const;
  // f += scale * sum_a lambda_a H_a(x)^T
  void add_forces(const VecX& x, const VecX& lambda, double scale, VecX& f) const;
  // out += scale * sum_a d(H_a^T lambda_a)/dx . dx
  void add_force_derivatives(const VecX& x, const VecX& lambda, const VecX& dx, double scale, VecX& out) const;
  // out += scale * sum_a (d(H_a^T lambda_a)/dx)^T y
  void add_force_derivatives_transpose(const VecX& x, const VecX& lambda, const VecX& y, double scale,
                                       VecX& out) const;
  // out (n_a) += scale * H_a(x) y, i.e. out_a += scale * y . H_a^T (the reverse of f += H_a^T dlambda).
  void add_jacobian_product(const VecX& x, const VecX& y, double scale, VecX& out) const;

  // Actuation stiffness in the static tangent: -sum_a d(H_a^T lambda_a)/dx restricted
  // to the cables, sum_cables lambda d^2L/dx^2 (exact, symmetric positive
  // semi-definite). Not included: pressure cavities (closed: p d^2V/dx^2 is exact and
  // symmetric but indefinite, so adding it can make the tangent indefinite where K
  // alone is not; open faces: not symmetric, and its symmetric part is not the
  // tangent) and servos (translation: H_a constant, no term; rotation: couples all
  // its nodes and is not symmetric). See method.md "Static equilibrium".
  //
  // The node cliques the cable stiffness couples, one per cable segment in actuator
  // order (Cable::segment_stencil's nodes): build_fem_model's `cliques`.
  std::vector<std::vector<int>> stiffness_cliques() const;
  // True when `pattern` was built with (a list starting with) stiffness_cliques().
  bool stiffness_fits(const fem::SystemPattern& pattern) const;
  // values (pattern.nnz(), upper triangle) += sum_cables lambda_a d^2L_a/dx^2 at x,
  // through the pattern's precomputed clique scatter (no search, no allocation).
  // Requires stiffness_fits(pattern) (checked in debug builds only).
  void add_stiffness(const VecX& x, const VecX& lambda, const fem::SystemPattern& pattern, double* values) const;
};

}  // namespace softdiff::actuation
