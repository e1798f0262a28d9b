#pragma once
// Derivatives of the contact stage with rigid bodies (issue 21; sibling of
// rigid_contact.hpp; docs/method.md "Derivatives", "Through contact with rigid bodies").
// The step with rigid bodies in contact (implicit Euler, one Newton iteration, dense
// backend) is
//   1. the rigid free step s_r -> s_r^free (rigid::step; its Jacobian J_f from
//      rigid_derivatives.hpp), u_free,r its velocities (joints: cdot_free T(s_r));
//   2. detection at the extended positions X = (x, x_k = p_r + R_r X_k);
//   3. the one NCP on G = h H_s A^{-1} H_s^T + h sum_r H_r W_r H_r^T, with H_r's rows
//      sum_k w_k C^T [I, -[rho_k]], rho_k = R_r X_k (the pose at the start of the step) and
//      W_r = T a^{-1} T^T, a = T^T diag(m I, R_f I R_f^T) T (R_f: the free orientation);
//   4. u_r = u_free,r + W_r P_r, P_r = h H_r^T lambda; the end pose from (s_r, u_r):
//      free p + h v, exp(h omega) q; hinge exp(delta n) about the anchor, delta = h n.omega;
//      slider p + h (n.v) n.
// Its derivative, the implicit derivative by contact mode as for the soft bodies, has per
// rigid body the linear maps built here from the step's record, with z_r = (d in_r (12),
// d params_r (7)) (rigid_derivatives.hpp's tangent and parameters):
//   - pseudo-node positions: dx_k = dp_r + dtheta_r x rho_k (feeds the detection's
//     geometry derivative, collision/contact_derivatives.hpp, on the extended positions);
//   - the impulse at fixed lambda: dP_r = sum_k [df_k; rho_k x df_k] + Q_r dtheta_r, df_k
//     the geometry's change of the force on pseudo-node k, Q_r = [0; sum_k [F_k][rho_k]]
//     (the lever arm's rotation), F_k = h sum_i w_k C_i lambda_i;
//   - du0_r = K0_r z_r + W_r dP_r: K0 = d u_free + dW[.] P_r (the free step's Jacobian
//     chained with u_free's and W_r's dependence on q_free, mass, inertia and, for a
//     hinge, T's on the position);
//   - sigma at fixed lambda: b_i += sum_k w_k C_i^T (du0_v + du0_omega x rho_k + omega x
//     (dtheta x rho_k));
//   - after the NCP's dlambda: du_r = du0_r + h W_r H_r^T dlambda, and the end pose
//     d out_r = E_in z_r + E_u du_r.
// Without contacts in the step the rigid bodies end at their free step: d out = J_f z.
// A fixed body's pose is carried over (J_f). All maps are fixed-size per body: no
// allocation per contact after the first step of a size.
//
// Joint limits in contact (rigid_contact.hpp "limit rows"; docs/method.md "Through contact
// with rigid bodies", limit rows): the step's NCP had L limit rows after the nc contacts
// (data.contact.rigid.limit_rows, their forces in limit_lambda; the record keeps only the
// contacts'), frictionless unilateral rows whose normal Jacobian on the body's (v, omega)
// is j = s T / |T|^2 (s = +1 lower, -1 upper) and gap the distance to the limit. By
// contact mode, an active limit (lambda > 0) is a bilateral row (sticking, its tangential
// rows decoupled with zero right-hand side: their force stays 0) and an inactive one
// drops (breaking). prepare() rebuilds the extended system of the solve: H_r^T with the
// limit columns, G (3 (nc + L)): the record's G, the limit rows' h H_r W_r j coupling and
// h j W_r j diagonal (equal tangential diagonals, as finish_limit_rows), sigma (the limit
// rows' s cdot(u) + gap / h), mu (0) and the modes; the NCP derivative runs on it. Per
// limit row, at fixed lambda:
//   - b_l = dj[z].u + j.du0 + s dc_n / h (dc_n = n.dtheta hinge, n.dp slider);
//   - dP_r += h lambda_l dj[z], dj = s / |T|^2 (I - 2 T T^T / |T|^2) dT, dT = [n x dp; 0]
//     for a hinge, 0 for a slider;
// and du_r = du0_r + h W_r H_r^T dlambda over the extended columns. A limited body's free
// velocity u_free is the UNCLAMPED free step's (begin_rigid_contact), so K0's du_free
// comes from that step's Jacobian; W's dependence on q_free stays the clamped free
// step's (the orientation W was formed with).
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>

#include <vector>

namespace softdiff::contact {

using Mat12x19 = Eigen::Matrix<double, 12, 19>;
using Mat6x19 = Eigen::Matrix<double, 6, 19>;

class RigidContactDerivative {
 public:
  // From the step's record (data.contact.rigid: in, free, u, W, Ht; data.rigid: the free
  // steps' StepInfo; data.contact: contacts, lambda) and the step's rigid end states.
  // G_contacts: the contacts' G for the limit rows' extended G (3 nc square) instead of the
  // dense record's (Newton: G with the converged tangent, ContactStageDerivative::full_G).
  void prepare(const Model& model, const Data& data, const std::vector<rigid::RigidState>& out, double h,
               const MatX* G_contacts = nullptr);
  bool with_contacts() const { return contacts_; }
  // How many times prepare ran (the step derivative calls it once per step: its cache key,
  // integrator::StepDerivatives::prepare_rigid; tests count it).
  long prepare_count() const { return prepares_; }

  // Tangents. z: 12 R (the rigid input states), zp: 7 R (mass, inertia per body); empty: zero.
  // dX: the extended positions' tangent; its pseudo-node part is set from z.
  void pseudo_position_jvp(const Model& model, const VecX& z, VecX& dX) const;
  // du0 (6R) from z, zp and r (the extended force change of add_force_jvp: its pseudo part).
  void impulse_jvp(const Model& model, const VecX& z, const VecX& zp, const VecX& r, VecX& du0) const;
  // b += the rigid rows' sigma change (du0 and the lever arm's rotation).
  void add_sigma_jvp(const Model& model, const ContactData& cd, const VecX& du0, const VecX& z, VecX& b) const;
  // The end states' tangent (12R) from z, zp, du0 and dlambda (with contacts), or J_f z.
  void out_jvp(const Model& model, const ContactData& cd, const VecX& z, const VecX& zp, const VecX& du0,
               const VecX& dlambda, VecX& d_out) const;

  // Cotangents, the transposes in reverse order. bar_out: 12R. Sets bar_z (12R), bar_zp
  // (7R) and bar_du0 (6R); bar_lambda += the rigid velocities' share.
  void out_vjp(const Model& model, const ContactData& cd, const VecX& bar_out, VecX& bar_z, VecX& bar_zp,
               VecX& bar_du0, VecX& bar_lambda) const;
  // bar_du0, bar_z += the transpose of add_sigma_jvp for bar_b.
  void add_sigma_vjp(const Model& model, const ContactData& cd, const VecX& bar_b, VecX& bar_du0, VecX& bar_z) const;
  // bar_z, bar_zp += K0^T bar_du0, Q^T bar_dP; y's pseudo part = bar_df (the cotangent of
  // add_force_jvp's output on the pseudo-nodes).
  void impulse_vjp(const Model& model, const VecX& bar_du0, VecX& bar_z, VecX& bar_zp, VecX& y) const;
  // bar_z += the transpose of pseudo_position_jvp for bar_X's pseudo part.
  void add_pseudo_position_vjp(const Model& model, const VecX& bar_X, VecX& bar_z) const;

  // The extended velocities (soft v, then each pseudo-node's v_r + omega_r x rho_k with
  // the corrected u_r) for the geometry terms of sigma.
  void extended_velocities(const Model& model, const ContactData& cd, const VecX& v, VecX& U) const;

  // Joint limits in the step's NCP (see above): L rows after the nc contacts.
  int limit_rows() const { return static_cast<int>(limits_.size()); }
  // The extended system of the solve (3 (nc + L)): G, mu, lambda, sigma and the modes by
  // contact mode (valid when limit_rows() > 0).
  const MatX& extended_G() const { return G_ext_; }
  // On the sparse backend (the record has no G; rpsp) the extended system is the
  // operator's instead: extended_G() is empty and extended_Kt() (k + 2L x 3 (nc + L)) the
  // rigid rows with the limit columns (rigid_contact.cpp rigid_delassus_rows), the soft
  // part h H_s A^-1 H_s^T with zero columns for the limit rows (with rigidified parts the
  // caller gives the operator's H_f^T and the parts' rows K_p beside it, rplim).
  bool extended_on_operator() const { return !limits_.empty() && G_ext_.rows() == 0; }
  const MatX& extended_Kt() const { return Kt_ext_; }
  const VecX& extended_mu() const { return mu_ext_; }
  const VecX& extended_lambda() const { return lambda_; }
  const VecX& extended_sigma() const { return sigma_ext_; }
  const std::vector<Mode>& extended_modes() const { return modes_ext_; }
  // b's limit rows (b: 3 (nc + L), its contact rows set by the caller): b_l = dj[z].u +
  // j.du0 + s dc_n / h, tangential rows 0.
  void limit_sigma_jvp(const VecX& z, const VecX& du0, VecX& b) const;
  // Its transpose: bar_du0, bar_z += for bar_b's limit rows.
  void add_limit_sigma_vjp(const VecX& bar_b, VecX& bar_du0, VecX& bar_z) const;

 private:
  struct Body {
    Mat12x19 Jf = Mat12x19::Zero();            // the free step [J.state J.params]
    Mat6x19 K0 = Mat6x19::Zero();              // du_free + dW[.] P at fixed impulse
    Eigen::Matrix<double, 6, 3> Q = Eigen::Matrix<double, 6, 3>::Zero();  // dP / dtheta (lever arm)
    rigid::Mat6 W = rigid::Mat6::Zero();
    rigid::Mat12 E_in = rigid::Mat12::Zero();  // d out / d in at fixed u
    Eigen::Matrix<double, 12, 6> E_u = Eigen::Matrix<double, 12, 6>::Zero();  // d out / d u
    Vec3 omega = Vec3::Zero();                 // the corrected angular velocity (u_r)
    bool dofs = false;
  };
  int body_of(const Model& model, int node) const;
  // A limit row of the step's NCP: its body, sign s, Jacobian j, dj / dp (hinge; 0 for a
  // slider), force, and d c_n / d z's block (TH for a hinge, P for a slider).
  struct Limit {
    int body = 0;
    double s = 1, lambda = 0;
    rigid::Vec6 j = rigid::Vec6::Zero();
    Eigen::Matrix<double, 6, 3> Mj = Eigen::Matrix<double, 6, 3>::Zero();
    int coordinate_block = 0;
    Vec3 axis = Vec3::UnitZ();
  };
  void prepare_limits(const Model& model, const Data& data, double h, const MatX* G_contacts);

  std::vector<Body> bodies_;
  std::vector<Limit> limits_;
  MatX Ht_;                    // (6R x 3 (nc + L)) H_r^T with the limit columns
  VecX u_;                     // (6R) the corrected velocities
  VecX lambda_;                // (3 (nc + L)) the contacts' forces, then the limits'
  MatX G_ext_;                 // (3 (nc + L)) square: the solve's G (limit rows only)
  MatX Kt_ext_;                // sparse backend: the extended rigid rows (extended_rigid_rows)
  void extended_rigid_rows(const Data& data);
  VecX mu_ext_, sigma_ext_;    //   its mu (nc + L), sigma (3 (nc + L))
  std::vector<Mode> modes_ext_;
  int nc_ = 0;
  VecX rho_;   // (3 pseudo) x_k - p_r of each pseudo-node at the start of the step
  VecX F_;     // (3 pseudo) the contact force on each pseudo-node, h sum_i w_k C_i lambda_i
  bool contacts_ = false;
  double h_ = 0;
  long prepares_ = 0;
};

}  // namespace softdiff::contact
