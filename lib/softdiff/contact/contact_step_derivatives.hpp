#pragma once
// Derivatives of the contact stage (sibling of contact_step.hpp; docs/method.md
// "Derivatives", "Through contact"): the pieces that the dynamic step's derivative
// (integrator/implicit_euler_derivatives.cpp) and the static equilibrium's
// (integrator/static_solver_derivatives.cpp) share. At a solution of the contact
// stage (data.contact: contacts, H_c^T, lambda, sigma, modes) of a linearized problem
// A u = b + h H_c^T lambda with sigma = H_c u + (0, 0, phi / h):
//  - the geometry derivative of every contact at the detection's positions x
//    (collision/contact_derivatives.hpp; zero where it does not exist);
//  - the NCP derivative with the modes fixed (ncp_derivatives.hpp), on the record's
//    dense G or, where the record has none (sparse backend) or the caller asks for
//    another A, on G_AA = h H_A A^{-1} H_A^T of the active contacts (one congruence
//    with the given factorization), or, beyond ncp.derivative_dense_max_active active
//    contacts, on the operator y -> G_AA y (mode_system.hpp: never a dense G_AA; when
//    A_upper is given, all sticking preconditioned by (G_AA + c I)^{-1}, mixed by the
//    reduced preconditioner with GMRES, at any size; without A_upper mixed sets only up
//    to 64 active contacts; the jvp / vjp then solve with `solver`, which must keep its
//    factorization);
//  - the products of the geometry terms: h dH[dx]^T lambda (the force), dH[dx] u +
//    (0, 0, dphi[dx] / h) (sigma at fixed lambda) and their transposes.
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/contact/ncp_derivatives.hpp>
#include <softdiff/contact/sparse_delassus.hpp>
#include <softdiff/core/parameters.hpp>
#include <softdiff/data.hpp>
#include <softdiff/model.hpp>

#include <vector>

namespace softdiff::contact {

class ContactStageDerivative {
 public:
  // Geometry derivatives of cd's contacts at x, and the NCP derivative at cd's solution.
  // G: cd.G when use_record_G and the record holds it; otherwise G_AA = h H_A A^{-1}
  // H_A^T with `solver` (A's factorization). Returns false if that solve failed.
  // modes, sigma: the modes and sigma the NCP derivative holds (default: cd's).
  // A_upper: the matrix `solver` factorized (upper triangle), for the operator path's
  // preconditioner (mode_system.hpp; nullptr: the operator path is unpreconditioned).
  // extended: the NCP derivative on this system instead (rigid bodies' joint limits in
  // contact: the contacts' rows then the limit rows, rigid_contact_derivatives.hpp); the
  // geometry derivatives stay the contacts'.
  // Without G (the sparse backend's record, rpsp): G_AA is formed as above from the
  // system's soft columns Ht (nullptr: cd.Ht; columns beyond Ht's have no soft dof: zero,
  // e.g. the limit rows) and rigid rows Kt (nullptr: cd.rigid.Kt with rigid bodies; the
  // limit rows' extended Kt) and Kt_more (rigidified parts: K_p = L_S^-1 W,
  // data.rigidify.SW, beside H_f^T = data.rigidify.Ht_soft), as the step's operator had
  // them: G_AA = h H_A A^-1 H_A^T + h [Kt; Kt_more]_A^T [Kt; Kt_more]_A.
  struct NcpSystem {
    const MatX* G = nullptr;
    const VecX *mu = nullptr, *lambda = nullptr, *sigma = nullptr;
    const std::vector<Mode>* modes = nullptr;
    const SparseMatrix* Ht = nullptr;
    const MatX *Kt = nullptr, *Kt_more = nullptr;
  };
  bool prepare(const Model& model, const ContactData& cd, const VecX& x, integrator::LinearSolver& solver, double h,
               bool use_record_G, const std::vector<Mode>* modes = nullptr, const VecX* sigma = nullptr,
               const SparseMatrix* A_upper = nullptr, const NcpSystem* extended = nullptr);

  // r += h sum_i dH_i[dx]^T lambda_i (the contact forces' change with the positions).
  void add_force_jvp(const ContactData& cd, double h, const VecX& dx, VecX& r) const;
  // b += dH[dx] u + (0, 0, dgap[dx] / h): sigma's change with the positions at fixed
  // lambda and fixed u (u: the solution of the linearized problem, v_f of the step).
  void add_sigma_jvp(const ContactData& cd, const VecX& u, double h, const VecX& dx, VecX& b) const;
  // bar_x += the transposes of both, for the cotangents y (of r) and bar_b (of b).
  void add_geometry_vjp(const ContactData& cd, const VecX& u, double h, const VecX& y, const VecX& bar_b,
                        VecX& bar_x) const;
  // static.friction load_step (docs/method.md *Load-step-anchored friction*, the face terms;
  // 2026-12-04, branch ffric): contact i's slip since the load step's start is measured
  // through its current weights w and frame t, s_ir = t_r . sum_k w_k D_k (r = 0, 1; D = X -
  // X^start on the positions cd's contacts number, the extended ones with rigid bodies).
  // Beside H_T dx (weights and frame held), its change with the positions has
  //     b_{3i+r} += dt_r[dx] . d_i + t_r . sum_k dw_k[dx] D_k,   d_i = sum_k w_k D_k,
  // the geometry derivative's dframe and dweights (zero on planes and box faces); the
  // normal rows are untouched. add_slip_vjp: bar_x += its transpose for the cotangent
  // bar_b (its tangential rows; rows beyond 3 nc ignored).
  void add_slip_jvp(const ContactData& cd, const VecX& D, const VecX& dx, VecX& b) const;
  void add_slip_vjp(const ContactData& cd, const VecX& D, const VecX& bar_b, VecX& bar_x) const;
  // dmu (nc) of a tangent of the parameters: dmu_i = sum of dp_j over the friction
  // parameters j whose pair rule contact i belongs to (empty if there is none).
  static void friction_tangent(const Model& model, const ContactData& cd, const std::vector<ParameterId>& parameters,
                               const VecX& dp, VecX& dmu);
  // bar_p_j += sum of bar_mu_i over the contacts of friction parameter j's pair rule.
  static void add_friction_cotangent(const Model& model, const ContactData& cd,
                                     const std::vector<ParameterId>& parameters, const VecX& bar_mu, VecX& bar_p);

  // The contacts' whole G = h H A^{-1} H^T (`solver`: A's factorization) plus, with rigid
  // bodies, h Kt^T Kt (rigid_rows): the dense G of the step with another A (Newton's
  // converged tangent A_f; the joint limits' extended G is built from it,
  // rigid_contact_derivatives.hpp). Returns false if the solve failed.
  // Rigidified parts (rplim): Ht the soft rows H_f^T (nullptr: cd.Ht) and Kt_more the
  // parts' rows K_f (3 nc columns; nullptr: none), G = h H_f A^{-1} H_f^T + h Kt^T Kt +
  // h K_f^T K_f, the reduced Delassus matrix (rigidify_derivatives.hpp newton_contact_rows).
  bool full_G(const Model& model, const ContactData& cd, integrator::LinearSolver& solver, double h, MatX& G,
              const SparseMatrix* Ht = nullptr, const MatX* Kt_more = nullptr);
  // The rigid bodies' rows Kt (k x 3 nc, h sum_r H_r W_r H_r^T = h Kt^T Kt): the sparse
  // record's, or formed from the dense record's H_r^T and L_r.
  const MatX& rigid_rows(const Model& model, const ContactData& cd);

  const NcpDerivative& ncp() const { return ncp_; }
  // The operator path's power iteration for the scale L (ncp().scale()) of the last
  // prepare where every active contact sticks (default-constructed otherwise: then L is
  // the sampled largest diagonal entry of G_AA).
  const PowerIteration& scale_iteration() const { return scale_; }
  // How many active contacts the mixed path's scale samples (docs/method.md "The
  // derivative's scale").
  static constexpr int scale_sample_contacts = 32;
  // ... solved in blocks of this many contacts (3 right-hand sides each): the memory of
  // the dense right-hand sides is 3 n x 3 block, not 3 n x 3 scale_sample_contacts.
  static constexpr int scale_sample_block_contacts = 4;
  // Contacts whose geometry derivative does not exist (taken as zero), and those whose
  // derivative is the randomized-smoothing estimate (model.contact.smoothing).
  int nondifferentiable_contacts() const { return nondifferentiable_; }
  int smoothed_contacts() const { return smoothed_; }

 private:
  std::vector<collision::ContactGeometryDerivative> geometry_;
  NcpDerivative ncp_;
  std::vector<int> active_ids_;  // G_AA path: the active contacts,
  SparseMatrix Ht_active_;       //   their columns of H_c^T
  MatX G_active_;                //   and G_AA (dense path; a batch's block on the operator path)
  PowerIteration scale_;         // operator path: the scale L's power iteration
  VecX scale_y_, scale_gy_;      //   its (3 na) iterate and product
  VecX scale_w_;                 //   (3n) A^{-1} H_A^T y of its last product: the next start
  MatX sample_B_, sample_X_;     // mixed sets: (3n x 3 block) a block of the sampled columns of H_A^T, A^{-1} times them
  bool sampled_max_diagonal(integrator::LinearSolver& solver, double h, double& L);
  VecX op_u_, op_w_;             // operator path: (3n) scratch of the products with G_AA
  SparseMatrix Ht_padded_;       // an NcpSystem's Ht with zero columns up to its Kt's (limit rows)
  MatX Kt_active_;               // rigid bodies: (k x 3 na) Kt's active columns
  MatX Kt_record_;               //   Kt formed from the dense record (rigid_rows)
  VecX op_k_;                    //   (k) scratch of their products
  // out += h Kt_A^T (Kt_A y): the rigid part of G_AA y (nothing without rigid rows).
  void add_rigid_product(double h, const VecX& y, VecX& out);
  SparseDelassus shifted_;       // operator path: (G_AA + c I)^{-1}, the preconditioner
  int nondifferentiable_ = 0, smoothed_ = 0;
};

}  // namespace softdiff::contact
