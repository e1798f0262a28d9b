#include <softdiff/actuation/actuation_model.hpp>

#include <softdiff/core/assert.hpp>

#include <algorithm>
#include <limits>
#include <string>

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

void ActuatorModel::add_force_derivative_transpose(const VecX& x, double lambda, const VecX& y, VecX& out) const {
  std::visit([&](const auto& a) { a.add_force_derivative_transpose(x, lambda, y, out); }, kind);
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

bool ActuationModel::conservative() const {
  for (const auto& a : actuators) {
    if (const auto* c = std::get_if<Cavity>(&a.kind); c && !c->closed()) return false;
    if (const auto* s = std::get_if<Servo>(&a.kind); s && s->is_rotation()) return false;
  }
  return true;
}

double ActuationModel::potential(const VecX& x, const VecX& lambda) const {
  double U = 0;
  for (size_t k = 0; k < actuators.size(); ++k) {
    const double l = lambda[static_cast<Eigen::Index>(k)];
    if (l == 0) continue;
    const auto& a = actuators[k];
    if (const auto* cable = std::get_if<Cable>(&a.kind)) {
      U += l * cable->length(x);  // H_a = -dL/dx: f = -d(lambda L)/dx
    } else if (const auto* cavity = std::get_if<Cavity>(&a.kind)) {
      U -= l * cavity->volume(x);  // H_a = dV/dx (closed)
    } else if (const auto* s = std::get_if<Servo>(&a.kind)) {
      Vec3 mean = Vec3::Zero();
      for (int i : s->nodes()) mean += x.segment<3>(3 * i);
      mean /= static_cast<double>(s->nodes().size());
      U -= l * s->direction().dot(mean);  // uniform lambda d / N on each node
    }
  }
  return U;
}

void ActuationModel::add_forces(const VecX& x, const VecX& lambda, double scale, VecX& f) const {
  for (size_t a = 0; a < actuators.size(); ++a) {
    const double l = lambda[static_cast<Eigen::Index>(a)];
    if (l != 0) actuators[a].add_force(x, l, scale, f);
  }
}

void ActuationModel::add_force_derivatives(const VecX& x, const VecX& lambda, const VecX& dx, double scale,
                                           VecX& out) const {
  // d(H_a^T lambda)/dx is linear in lambda: scale it into lambda.
  for (size_t a = 0; a < actuators.size(); ++a) {
    const double l = scale * lambda[static_cast<Eigen::Index>(a)];
    if (l != 0) actuators[a].add_force_derivative(x, l, dx, out);
  }
}

void ActuationModel::add_force_derivatives_transpose(const VecX& x, const VecX& lambda, const VecX& y, double scale,
                                                     VecX& out) const {
  for (size_t a = 0; a < actuators.size(); ++a) {
    const double l = scale * lambda[static_cast<Eigen::Index>(a)];
    if (l != 0) actuators[a].add_force_derivative_transpose(x, l, y, out);
  }
}

void ActuationModel::add_jacobian_product(const VecX& x, const VecX& y, double scale, VecX& out) const {
  SOFTDIFF_DEMAND(out.size() == static_cast<Eigen::Index>(actuators.size()),
                  "out: expected one value per actuator (" + std::to_string(actuators.size()) + "), got " +
                      std::to_string(out.size()));
  SOFTDIFF_DEMAND(y.size() == x.size(), "y must be sized like x");
  Mat3X values;
  for (size_t a = 0; a < actuators.size(); ++a) {
    double dot = 0;
    std::visit(
        [&](const auto& k) {
          const auto& nodes = k.nodes();
          values.resize(3, static_cast<Eigen::Index>(nodes.size()));
          k.gradient_sparse(x, values);
          for (size_t j = 0; j < nodes.size(); ++j)
            dot += values.col(static_cast<Eigen::Index>(j)).dot(y.segment<3>(3 * nodes[j]));
        },
        actuators[a].kind);
    out[static_cast<Eigen::Index>(a)] += scale * dot;
  }
}

std::vector<std::vector<int>> ActuationModel::stiffness_cliques() const {
  std::vector<std::vector<int>> cliques;
  for (const auto& a : actuators)
    if (const auto* c = std::get_if<Cable>(&a.kind))
      for (int s = 0; s < c->num_segments(); ++s) {
        const Cable::SegmentStencil st = c->segment_stencil(s);
        cliques.emplace_back(st.nodes.begin(), st.nodes.begin() + st.count);
      }
  return cliques;
}

bool ActuationModel::stiffness_fits(const fem::SystemPattern& pattern) const {
  const auto cliques = stiffness_cliques();
  if (static_cast<int>(cliques.size()) > pattern.num_cliques()) return false;
  for (size_t c = 0; c < cliques.size(); ++c) {
    const int begin = pattern.clique_node_begin[c], end = pattern.clique_node_begin[c + 1];
    if (!std::equal(cliques[c].begin(), cliques[c].end(), pattern.clique_nodes.begin() + begin,
                    pattern.clique_nodes.begin() + end))
      return false;
  }
  return true;
}

void ActuationModel::add_stiffness(const VecX& x, const VecX& lambda, const fem::SystemPattern& pattern,
                                   double* values) const {
  SOFTDIFF_DEMAND(lambda.size() == static_cast<Eigen::Index>(actuators.size()), "one value per actuator");
  int first_clique = 0;  // clique of the cable's segment 0
  for (size_t i = 0; i < actuators.size(); ++i) {
    const auto* c = std::get_if<Cable>(&actuators[i].kind);
    if (!c) continue;
    const double l = lambda[static_cast<Eigen::Index>(i)];
    if (l != 0) {
      c->for_each_stiffness_block(x, l, [&](int s, int a, int b, int, int, const Mat3& block) {
        const int clique = first_clique + s;
        SOFTDIFF_ASSERT(clique < pattern.num_cliques());
        const int k = pattern.clique_node_begin[clique + 1] - pattern.clique_node_begin[clique];
        const int* scatter = pattern.clique_scatter.data() + pattern.clique_scatter_begin[clique] + 9 * (a * k + b);
        for (int r = 0; r < 3; ++r)
          for (int q = 0; q < 3; ++q)
            if (scatter[3 * r + q] >= 0) values[scatter[3 * r + q]] += block(r, q);
      });
    }
    first_clique += c->num_segments();
  }
}

}  // namespace softdiff::actuation
