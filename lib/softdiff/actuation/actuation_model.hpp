#pragma once
// The actuation part of a Model: every actuator of every body with its value over
// time, and the effectors. Built by io::build_model. The actuation force on the
// nodes is +h H_a(x)^T lambda_a (method.md), evaluated at the step's x_i.
#include <softdiff/actuation/cable.hpp>
#include <softdiff/actuation/effector.hpp>
#include <softdiff/actuation/pressure.hpp>
#include <softdiff/actuation/servo.hpp>

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
  // f += scale * sum_a lambda_a H_a(x)^T
  void add_forces(const VecX& x, const VecX& lambda, double scale, VecX& f) const;
};

}  // namespace softdiff::actuation
