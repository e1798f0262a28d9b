#pragma once
// Servo actuator (method.md "Actuation Jacobians"): a prescribed-direction force, or
// a torque about a fixed axis, on a node set.
//
// Translation servo, unit direction d: node i of the N nodes receives lambda d / N
// (uniform weights, summing to 1; chosen over lumped-mass weights so that the
// actuator needs no mass and its meaning does not change with the mesh density of
// its patch). The resultant force is lambda d (to rounding), the resultant moment
// about the patch centroid is zero, and H_a (constant) has d / N on each node.
//
// Rotation servo, unit axis a through center c, torque lambda: with
// r_i = (I - a a^T)(x_i - c) the moment arm of node i and S = sum_j |r_j|^2,
//
//     f_i = lambda (a x r_i) / S.
//
// Since r_i x (a x r_i) = a |r_i|^2 (r_i is perpendicular to a), the moment about the
// axis is a . sum_i (x_i - c) x f_i = lambda exactly (the axial component of x_i - c
// contributes nothing to a . (...)). Each f_i is tangential (perpendicular to a and
// to r_i). The resultant FORCE is NOT zero in general: sum_i f_i = lambda N (a x rbar) / S with
// rbar the mean moment arm; it vanishes when the nodes' centroid lies on the axis
// (a symmetric patch around the axis). The full moment about c also has an
// off-axis part, -lambda (sum_i s_i r_i) / S with s_i = a . (x_i - c) (zero for a
// planar patch perpendicular to the axis). H_a is this field for lambda = 1; it
// depends on x: add_force_derivative gives its exact directional derivative,
//     d f_i = lambda [ (a x dx_i) / S - (a x r_i) dS / S^2 ],  dS = 2 sum_j r_j . dx_j
// (a x dr_i = a x dx_i and r_j . dr_j = r_j . dx_j since r_j, dr_j are perpendicular
// to a). Nodes on the axis (r_i = 0) get no force and are handled like any other.
// If every node is on the axis (S = 0) there is no moment arm: `rotation` rejects
// that at rest, and an evaluation where S = 0 adds nothing.
//
// Every evaluation is allocation-free.
#include <softdiff/core/types.hpp>

#include <string>
#include <vector>

namespace softdiff::actuation {

enum class ServoError {
  none,
  empty,           // no node
  bad_index,       // a node index outside [0, n)
  zero_direction,  // direction or axis of (near) zero length
  all_on_axis,     // rotation: every node on the axis at rest (no moment arm)
};

struct ServoStatus {
  ServoError error = ServoError::none;
  int node = -1;  // bad_index: the offending entry's value
  bool ok() const { return error == ServoError::none; }
  std::string message() const;
};

class Servo {
 public:
  // nodes: global indices (duplicates are removed); x_rest (3n) the rest positions,
  // used to check the indices (and, for a rotation, the moment arms). The direction /
  // axis is normalized (any non-zero length is accepted). On error `out` is left empty.
  static ServoStatus translation(std::vector<int> nodes, const Vec3& direction, const VecX& x_rest, Servo& out);
  static ServoStatus rotation(std::vector<int> nodes, const Vec3& axis, const Vec3& center, const VecX& x_rest,
                              Servo& out);

  bool is_rotation() const { return rotation_; }
  const Vec3& direction() const { return d_; }  // translation direction or rotation axis (unit)
  const Vec3& center() const { return c_; }

  // f += scale * lambda * H_a^T.
  void add_force(const VecX& x, double lambda, double scale, VecX& f) const;
  // H = H_a^T (overwritten; sized like x).
  void gradient(const VecX& x, VecX& H) const;
  // Sparse form: the servo's nodes (sorted, distinct), values (3, nodes().size()).
  const std::vector<int>& nodes() const { return nodes_; }
  void gradient_sparse(const VecX& x, Mat3X& values) const;
  // out += d(H_a^T lambda)/dx . dx (exact; zero for a translation servo).
  void add_force_derivative(const VecX& x, double lambda, const VecX& dx, VecX& out) const;
  // out += (d(H_a^T lambda)/dx)^T y: node j gets lambda [ (y_j x a) / S - 2 r_j k / S^2 ],
  // k = sum_i y_i . (a x r_i) (zero for a translation servo).
  void add_force_derivative_transpose(const VecX& x, double lambda, const VecX& y, VecX& out) const;

 private:
  Vec3 arm(const VecX& x, int node) const {  // r_i
    const Vec3 y = x.segment<3>(3 * node) - c_;
    return y - d_ * d_.dot(y);
  }
  double arm_sum(const VecX& x) const;  // S
  void check_sizes(const VecX& x, const VecX& out) const;

  bool rotation_ = false;
  Vec3 d_ = Vec3::Zero(), c_ = Vec3::Zero();
  std::vector<int> nodes_;
  long min_size_ = 0;
};

}  // namespace softdiff::actuation
