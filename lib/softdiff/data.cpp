#include <softdiff/data.hpp>

#include <softdiff/core/assert.hpp>

#include <algorithm>
#include <sstream>

namespace softdiff {

Data::Data(const Model& model) {
  const int ndof = 3 * model.fem.num_nodes;
  fem.resize(model.fem);
  K_i_values = VecX::Zero(model.fem.pattern.nnz());
  A = model.fem.pattern.structure;
  rhs = VecX::Zero(ndof);
  dv = VecX::Zero(ndof);
  Mv = VecX::Zero(ndof);
  Mvi = VecX::Zero(ndof);
  Kv = VecX::Zero(ndof);
  x_iter = VecX::Zero(ndof);
  v_iter = VecX::Zero(ndof);
  lambda_a = VecX::Zero(static_cast<Eigen::Index>(model.actuation.actuators.size()));
  f_act = VecX::Zero(ndof);
  solver = integrator::make_linear_solver(model.solver);
  rigid.resize(model.rigid.size());
  if (model.contact.enabled) {
    contact.detector = std::make_unique<collision::CollisionDetector>(model.contact.detection);
    contact.v_free = VecX::Zero(ndof);
    contact.correction = VecX::Zero(ndof);
    contact.rhs = VecX::Zero(ndof);
  }
}

void Data::restart(const Model& model, bool detection_changed) {
  const Eigen::Index ndof = 3L * model.fem.num_nodes;
  SOFTDIFF_DEMAND(rhs.size() == ndof && K_i_values.size() == model.fem.pattern.nnz() &&
                      lambda_a.size() == static_cast<Eigen::Index>(model.actuation.actuators.size()) &&
                      static_cast<bool>(contact.detector) == model.contact.enabled,
                  "Data::restart: not the scene this Data was built for");
  fem.resize(model.fem);
  fem.energy = 0;
  fem.bad_element = -1;
  fem.bad_det = 0;
  K_i_values.setZero();
  const SparseMatrix& S = model.fem.pattern.structure;
  std::copy(S.valuePtr(), S.valuePtr() + S.nonZeros(), A.valuePtr());
  for (VecX* v : {&rhs, &dv, &Mv, &Kv, &Mvi, &lambda_a, &f_act, &x_iter, &v_iter}) v->setZero();
  factor_is_current = false;
  if (solver) solver->refactorize_next();  // factor reuse: no factor kept from the previous run
  A_h = 0;
  linearized_x.resize(0);
  h = 0;
  history_weight = 0;
  hat = State{};
  newton_iterations_used = 0;
  newton_residual = 0;
  static_load_step_start.resize(0);
  static_load_step_start_extended.resize(0);
  static_shifted_iterations = 0;
  timings = {};
  factorizations = 0;
  if (model.contact.enabled) {
    ContactData fresh;
    fresh.detector = detection_changed ? std::make_unique<collision::CollisionDetector>(model.contact.detection)
                                       : std::move(contact.detector);
    fresh.v_free = std::move(contact.v_free);
    fresh.correction = std::move(contact.correction);
    fresh.rhs = std::move(contact.rhs);
    for (VecX* v : {&fresh.v_free, &fresh.correction, &fresh.rhs}) v->setZero();
    contact = std::move(fresh);
  }
}

namespace {

const fem::BodyModel* body_of_node(const Model& model, int node) {
  for (const auto& b : model.fem.bodies)
    if (node >= b.node_begin && node < b.node_begin + b.num_nodes) return &b;
  return nullptr;
}

const fem::BodyModel* body_of_element(const Model& model, int e) {
  if (e < 0 || e >= model.fem.num_tets) return nullptr;
  return &model.fem.bodies[model.fem.tet_body[e]];
}

std::string node_name(const Model& model, int dof) {
  const int node = dof / 3;
  const auto* b = body_of_node(model, node);
  if (!b) return "dof " + std::to_string(dof);
  const int local = node - b->node_begin;
  std::ostringstream s;
  s << "node " << local;
  if (local < static_cast<int>(b->mesh.file_tag.size())) s << " (gmsh tag " << b->mesh.file_tag[local] << ")";
  s << " of body '" << b->name << "', component " << "xyz"[dof % 3];
  return s.str();
}

}  // namespace

std::string describe(const Model& model, const StepStatus& st) {
  std::ostringstream s;
  if (st.step >= 0) s << (model.step.integrator == IntegratorKind::static_equilibrium ? "load step " : "step ") << st.step << ": ";
  switch (st.code) {
    case StepStatus::Code::ok: s << "ok"; break;
    case StepStatus::Code::inverted_element: {
      const auto* b = body_of_element(model, st.element);
      s << "inverted element: tetrahedron " << (b ? st.element - b->tet_begin : st.element);
      if (b) s << " of body '" << b->name << "'";
      s << " has det F = " << st.value << " <= 0";
      break;
    }
    case StepStatus::Code::not_positive_definite:
      s << "the system matrix is not positive definite";
      if (st.dof >= 0) s << " (pivot failed at " << node_name(model, st.dof) << ")";
      s << "; the stiffness is indefinite (large compression: try psd_projection: true, a smaller dt, "
           "or newton_iterations > 1) or, for a static solve, a body is not held by fixed nodes";
      break;
    case StepStatus::Code::non_finite:
      s << "non-finite value (NaN or Inf)";
      if (st.dof >= 0) s << " at " << node_name(model, st.dof);  // (a rigid body: named in detail)
      break;
    case StepStatus::Code::diverged:
      s << "diverged: " << node_name(model, st.dof) << " moved " << st.value << " m from rest, more than "
        << model.step.divergence_factor << " times its body's size";
      break;
    case StepStatus::Code::not_converged:
      s << "Newton did not converge in " << st.iterations << " iterations (relative residual " << st.residual << ")";
      break;
    case StepStatus::Code::solver_failed: s << "linear solver failed"; break;
    case StepStatus::Code::contact_not_converged: s << "contact solver did not converge"; break;
  }
  if (!st.detail.empty() && st.code != StepStatus::Code::not_positive_definite) s << ": " << st.detail;
  return s.str();
}

}  // namespace softdiff
