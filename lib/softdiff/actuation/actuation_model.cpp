#include <softdiff/actuation/actuation_model.hpp>

#include <limits>

namespace softdiff::actuation {

double Schedule::at(double t) const {
  if (points.empty()) return constant;
  if (t <= points.front()[0]) return points.front()[1];
  if (t >= points.back()[0]) return points.back()[1];
  for (size_t k = 1; k < points.size(); ++k)
    if (t <= points[k][0]) {
      const auto& a = points[k - 1];
      const auto& b = points[k];
      const double s = (t - a[0]) / (b[0] - a[0]);
      return (1 - s) * a[1] + s * b[1];
    }
  return points.back()[1];
}

namespace {
template <class... Fs>
struct overloaded : Fs... {
  using Fs::operator()...;
};
template <class... Fs>
overloaded(Fs...) -> overloaded<Fs...>;
}  // namespace

const char* ActuatorModel::kind_name() const {
  return std::visit(overloaded{[](const Cable&) { return "cable"; }, [](const Cavity&) { return "pressure"; },
                               [](const Servo&) { return "servo"; }},
                    kind);
}

void ActuatorModel::add_force(const VecX& x, double lambda, double scale, VecX& f) const {
  std::visit([&](const auto& a) { a.add_force(x, lambda, scale, f); }, kind);
}

void ActuatorModel::add_force_derivative(const VecX& x, double lambda, const VecX& dx, VecX& out) const {
  std::visit([&](const auto& a) { a.add_force_derivative(x, lambda, dx, out); }, kind);
}

bool ActuatorModel::has_measure() const {
  if (std::holds_alternative<Cable>(kind)) return true;
  if (const auto* c = std::get_if<Cavity>(&kind)) return c->closed();
  return false;
}

const char* ActuatorModel::measure_name() const {
  if (std::holds_alternative<Cable>(kind)) return "length";
  if (has_measure()) return "volume";
  return "";
}

double ActuatorModel::measure(const VecX& x) const {
  if (const auto* c = std::get_if<Cable>(&kind)) return c->length(x);
  if (const auto* c = std::get_if<Cavity>(&kind); c && c->closed()) return c->volume(x);
  return std::numeric_limits<double>::quiet_NaN();
}

void ActuationModel::values(double t, VecX& lambda) const {
  lambda.resize(static_cast<Eigen::Index>(actuators.size()));
  for (size_t a = 0; a < actuators.size(); ++a) lambda[static_cast<Eigen::Index>(a)] = actuators[a].value.at(t);
}

void ActuationModel::add_forces(const VecX& x, const VecX& lambda, double scale, VecX& f) const {
  for (size_t a = 0; a < actuators.size(); ++a) {
    const double l = lambda[static_cast<Eigen::Index>(a)];
    if (l != 0) actuators[a].add_force(x, l, scale, f);
  }
}

}  // namespace softdiff::actuation
