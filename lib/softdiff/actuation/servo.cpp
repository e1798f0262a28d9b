#include <softdiff/actuation/servo.hpp>
#include <softdiff/core/assert.hpp>

#include <Eigen/Geometry>
#include <algorithm>
#include <sstream>

namespace softdiff::actuation {

std::string ServoStatus::message() const {
  std::ostringstream s;
  switch (error) {
    case ServoError::none: s << "ok"; break;
    case ServoError::empty: s << "the servo has no node"; break;
    case ServoError::bad_index: s << "node index " << node << " is outside the model's nodes"; break;
    case ServoError::zero_direction: s << "the direction (or axis) has zero length"; break;
    case ServoError::all_on_axis: s << "every node of the servo lies on its axis: no moment arm"; break;
  }
  return s.str();
}

namespace {

ServoStatus prepare(std::vector<int>& nodes, const Vec3& direction, const VecX& x_rest, Vec3& unit) {
  ServoStatus status;
  if (nodes.empty()) {
    status.error = ServoError::empty;
    return status;
  }
  const long n = x_rest.size() / 3;
  for (int i : nodes)
    if (i < 0 || i >= n) {
      status.error = ServoError::bad_index;
      status.node = i;
      return status;
    }
  std::sort(nodes.begin(), nodes.end());
  nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
  const double norm = direction.norm();
  if (!(norm > 1e-12) || !direction.allFinite()) {
    status.error = ServoError::zero_direction;
    return status;
  }
  unit = direction / norm;
  return status;
}

}  // namespace

ServoStatus Servo::translation(std::vector<int> nodes, const Vec3& direction, const VecX& x_rest, Servo& out) {
  out = Servo();
  Vec3 d;
  ServoStatus status = prepare(nodes, direction, x_rest, d);
  if (!status.ok()) return status;
  out.d_ = d;
  out.nodes_ = std::move(nodes);
  out.min_size_ = 3L * (out.nodes_.back() + 1);
  return status;
}

ServoStatus Servo::rotation(std::vector<int> nodes, const Vec3& axis, const Vec3& center, const VecX& x_rest,
                            Servo& out) {
  out = Servo();
  Vec3 a;
  ServoStatus status = prepare(nodes, axis, x_rest, a);
  if (!status.ok()) return status;
  Servo s;
  s.rotation_ = true;
  s.d_ = a;
  s.c_ = center;
  s.nodes_ = std::move(nodes);
  s.min_size_ = 3L * (s.nodes_.back() + 1);
  double spread = 0;
  for (int i : s.nodes_) spread += (x_rest.segment<3>(3 * i) - center).squaredNorm();
  if (!(s.arm_sum(x_rest) > 1e-20 * spread)) {
    status.error = ServoError::all_on_axis;
    return status;
  }
  out = std::move(s);
  return status;
}

double Servo::arm_sum(const VecX& x) const {
  double S = 0;
  for (int i : nodes_) S += arm(x, i).squaredNorm();
  return S;
}

void Servo::check_sizes(const VecX& x, const VecX& out) const {
  SOFTDIFF_DEMAND(!nodes_.empty(), "the servo was not created");
  SOFTDIFF_DEMAND(x.size() >= min_size_ && x.size() % 3 == 0, "x is too short for the servo's nodes");
  SOFTDIFF_DEMAND(out.size() == x.size(), "output vector must be sized like x");
}

void Servo::add_force(const VecX& x, double lambda, double scale, VecX& f) const {
  check_sizes(x, f);
  if (!rotation_) {
    const Vec3 g = (scale * lambda / static_cast<double>(nodes_.size())) * d_;
    for (int i : nodes_) f.segment<3>(3 * i) += g;
    return;
  }
  const double S = arm_sum(x);
  if (!(S > 0)) return;
  const double s = scale * lambda / S;
  for (int i : nodes_) f.segment<3>(3 * i) += s * d_.cross(arm(x, i));
}

void Servo::gradient(const VecX& x, VecX& H) const {
  check_sizes(x, H);
  H.setZero();
  add_force(x, 1.0, 1.0, H);
}

void Servo::gradient_sparse(const VecX& x, Mat3X& values) const {
  SOFTDIFF_DEMAND(!nodes_.empty() && x.size() >= min_size_, "x is too short for the servo's nodes");
  SOFTDIFF_DEMAND(values.cols() == static_cast<Eigen::Index>(nodes_.size()), "values must be (3, nodes().size())");
  const int N = static_cast<int>(nodes_.size());
  if (!rotation_) {
    values.colwise() = d_ / N;
    return;
  }
  const double S = arm_sum(x);
  if (!(S > 0)) {
    values.setZero();
    return;
  }
  for (int j = 0; j < N; ++j) values.col(j) = d_.cross(arm(x, nodes_[j])) / S;
}

void Servo::add_force_derivative(const VecX& x, double lambda, const VecX& dx, VecX& out) const {
  check_sizes(x, out);
  SOFTDIFF_DEMAND(dx.size() == x.size(), "dx must be sized like x");
  if (!rotation_) return;
  double S = 0, dS = 0;
  for (int i : nodes_) {
    const Vec3 r = arm(x, i);
    S += r.squaredNorm();
    dS += 2 * r.dot(dx.segment<3>(3 * i));
  }
  if (!(S > 0)) return;
  const double s = lambda / S, t = lambda * dS / (S * S);
  for (int i : nodes_) out.segment<3>(3 * i) += s * d_.cross(dx.segment<3>(3 * i)) - t * d_.cross(arm(x, i));
}

void Servo::add_force_derivative_transpose(const VecX& x, double lambda, const VecX& y, VecX& out) const {
  check_sizes(x, out);
  SOFTDIFF_DEMAND(y.size() == x.size(), "y must be sized like x");
  if (!rotation_) return;
  double S = 0, k = 0;
  for (int i : nodes_) {
    const Vec3 r = arm(x, i);
    S += r.squaredNorm();
    k += y.segment<3>(3 * i).dot(d_.cross(r));
  }
  if (!(S > 0)) return;
  const double s = lambda / S, t = 2 * lambda * k / (S * S);
  for (int i : nodes_) out.segment<3>(3 * i) += s * y.segment<3>(3 * i).cross(d_) - t * arm(x, i);
}

}  // namespace softdiff::actuation
