#include <softdiff/contact/contact_step.hpp>

#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/timer.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>

namespace softdiff::contact {

namespace {

// Keep the widened pairs only where their own motion can close the gap: a contact
// further than the model's margin stays if gap < margin + 2 h |v_rel| (v_rel, the
// relative velocity of its two points under v_i or v_free, whichever is faster; the
// factor 2 covers the acceleration the contact forces themselves may cause).
// A contact none of whose nodes can move (all their dofs fixed) has H_i = 0: its row
// of the NCP would read sigma_i = g_i whatever lambda_i, infeasible if the two fixed
// parts overlap (a self-contact inside a clamped region). It is dropped.
// Between soft surfaces only the model's margin counts on the penetrating side: a
// vertex behind a triangle by more than that is the other face of a thin part, not a
// contact. margin: the (widened) margin detection used; v_i, v_free: the velocities.
void drop_inert_contacts(const Model& model, double h, double margin, const VecX& v_i, const VecX& v_free,
                         std::vector<collision::Contact>& list) {
  const auto& fixed = model.fem.fixed;
  const double base = model.contact.detection.margin;
  const bool widened = margin > base;
  const int n = model.fem.num_nodes;
  // A rigid body's pseudo-node (k >= n) moves unless the body is on a fixed joint.
  auto node_fixed = [&](int k) {
    if (k >= n)
      return model.rigid[static_cast<std::size_t>(model.contact.rigid_node_body[static_cast<std::size_t>(k - n)])]
                 .joint.kind == rigid::Joint::Kind::fixed;
    return fixed[3 * k] && fixed[3 * k + 1] && fixed[3 * k + 2];
  };
  list.erase(std::remove_if(list.begin(), list.end(),
                            [&](const collision::Contact& c) {
                              bool movable = false;
                              for (int k = 0; k < c.count && !movable; ++k)
                                movable = c.weights[k] != 0 && !node_fixed(c.nodes[k]);
                              if (!movable) return true;
                              if (!widened) return false;
                              if (c.kind != collision::ContactKind::vertex_obstacle && c.gap <= -base) return true;
                              if (c.gap < base) return false;
                              Vec3 a = Vec3::Zero(), b = Vec3::Zero();
                              for (int k = 0; k < c.count; ++k) {
                                a += c.weights[k] * v_free.segment<3>(3 * c.nodes[k]);
                                b += c.weights[k] * v_i.segment<3>(3 * c.nodes[k]);
                              }
                              return !(c.gap < base + 2 * h * std::max(a.norm(), b.norm()));
                            }),
             list.end());
}

// An edge-edge contact one of whose edges lies inside a planar face of a rigid body (its
// two triangles coplanar to round-off: a box face's diagonal) is dropped. The distance
// from the other edge to that plane is affine along it, so its closest approach to the
// face is at its endpoints (vertex-triangle contacts) or where it crosses the face's
// boundary edges (edge-edge contacts with those): the dropped row is redundant. Kept, its
// normal (the two edges' cross product) tilts away from the face's as soon as the bodies
// tilt apart, and a box landing flat on a box had sticking rows of inconsistent normals:
// the NCP answered a 1e-7 tilt with friction forces of ~1 N and a sliding row, the
// derivative with a spurious yaw (configs/rigid_stack.yaml; docs/method.md "Scenes of
// rigid bodies only", *Resting rigid-rigid contacts*). Rigid-rigid pairs only: a soft face
// bends (its contact set would switch as it does), and soft-rigid scenes keep their
// contacts as measured. In place.
void drop_planar_rigid_edges(const Model& model, std::vector<collision::Contact>& list) {
  const int n = model.fem.num_nodes;
  const auto& surfaces = model.contact.detection.surfaces;
  // The flags are the rigid surfaces' (collision::mark_planar_edges at model build, from
  // the body's local vertices): O(1) per contact. A contact's edge is feature_a / feature_b,
  // a column of its side's surface edges.
  auto planar = [&](int side, int edge) {
    const auto& flags = surfaces[static_cast<std::size_t>(side)].planar_edge;
    SOFTDIFF_DEMAND(static_cast<Eigen::Index>(flags.size()) == surfaces[static_cast<std::size_t>(side)].edges.cols(),
                    "drop_planar_rigid_edges: rigid surface '" + surfaces[static_cast<std::size_t>(side)].name +
                        "' has no planar-edge flags (contact::add_rigid_surfaces)");
    return flags[static_cast<std::size_t>(edge)] != 0;
  };
  list.erase(std::remove_if(list.begin(), list.end(),
                            [&](const collision::Contact& c) {
                              return c.kind == collision::ContactKind::edge_edge && c.nodes[0] >= n &&
                                     c.nodes[2] >= n && (planar(c.side_a, c.feature_a) || planar(c.side_b, c.feature_b));
                            }),
             list.end());
}

}  // namespace

void contact_jacobian_transpose(const Model& model, const collision::ContactSet& contacts, SparseMatrix& Ht) {
  const int ndof = 3 * model.fem.num_nodes;
  const int nc = contacts.size();
  Ht.resize(ndof, 3 * nc);
  Ht.setZero();
  // Each column holds 3 entries per node of the contact.
  Eigen::VectorXi per_column(3 * nc);
  for (int i = 0; i < nc; ++i) per_column.segment<3>(3 * i).setConstant(3 * contacts.contacts[i].count);
  Ht.reserve(per_column);
  const auto& fixed = model.fem.fixed;
  for (int i = 0; i < nc; ++i) {
    const auto& c = contacts.contacts[i];
    for (int r = 0; r < 3; ++r) {
      const Vec3 axis = c.frame.col(r);
      // Sorted rows within a column: nodes in increasing order.
      std::array<int, 4> order{0, 1, 2, 3};
      for (int a = 1; a < c.count; ++a)  // insertion sort of at most 4
        for (int b = a; b > 0 && c.nodes[order[b]] < c.nodes[order[b - 1]]; --b) std::swap(order[b], order[b - 1]);
      for (int q = 0; q < c.count; ++q) {
        const int k = order[q];
        if (c.nodes[k] >= model.fem.num_nodes) continue;  // a rigid body's pseudo-node: rigid_contact.hpp
        for (int d = 0; d < 3; ++d) {
          const int dof = 3 * c.nodes[k] + d;
          const double value = c.weights[k] * axis[d];
          if (!fixed[dof] && value != 0) Ht.coeffRef(dof, 3 * i + r) += value;
        }
      }
    }
  }
  Ht.makeCompressed();
}

StepStatus resolve_contacts(const Model& model, Data& data, const State& in, VecX& v, long step_index, double h) {
  return resolve_contacts(model, data, in.x, in.v, h, v, step_index, true);
}

StepStatus resolve_contacts(const Model& model, Data& data, const VecX& x, const VecX& v_previous, double h, VecX& v,
                            long step_index, bool free_motion_widens) {
  detect_contacts(model, data, x, v_previous, h, v, free_motion_widens);
  return solve_contact_problem(model, data, h, v, step_index);
}

std::uint64_t next_record_serial() {
  static std::atomic<std::uint64_t> serial{0};
  return ++serial;
}

void detect_contacts(const Model& model, Data& data, const VecX& x, const VecX& v_previous, double h, const VecX& v,
                     bool free_motion_widens) {
  auto& cd = data.contact;
  cd.serial = next_record_serial();
  auto t0 = Clock::now();
  // Speculative margin: a pair further apart than the margin at x_i may still close
  // within the step. Widening the margin to twice the largest node displacement the
  // step predicts (h max |v| over v_i and v_free; twice for two moving sides) keeps
  // every such pair in the NCP: its gap term phi / h lets it approach by exactly phi,
  // and it carries no force unless it closes (docs/method.md "Contact"). Per surface:
  // m_k = max(margin, 2 h max |v|) over surface k's vertices, a pair using the larger of
  // its two (detection.hpp): a free rigid body's free fall (g h per step) then widens its
  // own pairs, not the fingers' self-contact search (issue 21, docs/performance.md).
  const bool rigid = model.contact.with_rigid();
  if (rigid) extend_for_detection(model, data, x, v_previous, v);  // pseudo-nodes after the soft nodes
  const VecX& vp = rigid ? cd.rigid.v_previous : v_previous;
  const VecX& vf = rigid ? cd.rigid.v_free : v;
  const auto& surfaces = model.contact.detection.surfaces;
  cd.surface_margin.resize(surfaces.size());
  double margin = model.contact.detection.margin;
  for (std::size_t k = 0; k < surfaces.size(); ++k) {
    SOFTDIFF_DEMAND(!surfaces[k].vertices.empty() || surfaces[k].triangles.cols() == 0,
                    "detect_contacts: surface '" + surfaces[k].name + "' is not prepared (collision::make_surface)");
    double speed = 0;
    for (int node : surfaces[k].vertices)
      speed = std::max({speed, free_motion_widens ? vf.segment<3>(3 * node).squaredNorm() : 0.0,
                        vp.segment<3>(3 * node).squaredNorm()});
    cd.surface_margin[k] = std::max(model.contact.detection.margin, 2 * h * std::sqrt(speed));
    margin = std::max(margin, cd.surface_margin[k]);
  }
  cd.margin = margin;
  if (rigid) {
    cd.stats = cd.detector->detect(cd.rigid.x, cd.contacts, cd.surface_margin);
    drop_inert_contacts(model, h, margin, cd.rigid.v_previous, free_motion_widens ? cd.rigid.v_free : cd.rigid.v_previous,
                        cd.contacts.contacts);
    drop_planar_rigid_edges(model, cd.contacts.contacts);
    // A rigid body's resting manifold on an obstacle face: its extreme points only (exact;
    // rigid_contact.hpp reduce_rigid_manifolds).
    if (model.contact.reduce_rigid_manifolds) reduce_rigid_manifolds(model, data, cd.contacts.contacts);
  } else {
    cd.stats = cd.detector->detect(x, cd.contacts, cd.surface_margin);
    drop_inert_contacts(model, h, margin, v_previous, free_motion_widens ? v : v_previous, cd.contacts.contacts);
  }
  data.timings.detection += seconds_since(t0);
  t0 = Clock::now();
  if (cd.contacts.size() > 0) contact_jacobian_transpose(model, cd.contacts, cd.Ht);
  if (cd.contacts.size() > 0 && model.contact.with_rigid())
    rigid_jacobian_transpose(model, cd.contacts, cd.rigid.in, cd.rigid.Ht);
  cd.mu.resize(cd.contacts.size());
  for (int i = 0; i < cd.contacts.size(); ++i) cd.mu[i] = cd.contacts.contacts[i].mu;
  data.timings.delassus += seconds_since(t0);
}

void clear_contact_record(ContactData& cd) {
  cd.serial = next_record_serial();
  cd.contacts.contacts.clear();
  cd.result = {};
  cd.result.converged = true;
  cd.lambda.resize(0);
  cd.sigma.resize(0);
  cd.modes.clear();
  cd.previous_keys.clear();
  cd.previous_lambda.resize(0);
}

namespace {

StepStatus solve_contact_problem(const Model& model, Data& data, double h, VecX& v, long step_index, bool all_limits);
}  // namespace

StepStatus solve_contact_problem(const Model& model, Data& data, double h, VecX& v, long step_index) {
  return solve_contact_problem(model, data, h, v, step_index, false);
}

namespace {
// all_limits: every joint limit a row of the NCP (the retry when an unselected one was
// crossed; rigid_contact.hpp select_limit_rows).
StepStatus solve_contact_problem(const Model& model, Data& data, double h, VecX& v, long step_index, bool all_limits) {
  auto& cd = data.contact;
  cd.serial = next_record_serial();
  StepStatus status;
  status.step = step_index;
  const int nc = cd.contacts.size();
  cd.v_free = v;
  if (nc == 0) {
    clear_contact_record(cd);
    return status;
  }

  // G = h H A^{-1} H^T (dense backend) or its operator (sparse backend),
  // g = H v_free + phi / h on normal rows.
  auto t0 = Clock::now();
  const auto& ncp = model.contact.ncp;
  // With rigid bodies, either backend: the operator takes their rows h K K^T
  // (SparseDelassus::set_rigid; docs/method.md "Rigid bodies in contact", Backends).
  const bool with_rigid = model.contact.with_rigid();
  // Rigidified parts of soft bodies (integrator/rigidify.hpp): G and the correction
  // through the reduced solve; on the sparse backend the operator on the soft rows H_f
  // plus the parts' rank-6m part as rigid rows (rigidified_rows).
  const bool rigidified = !model.rigidify.empty();
  // A scene of rigid bodies only (no soft dof: nothing factorized) takes either backend:
  // the operator then has the rigid rows alone (SparseDelassus with an empty soft part:
  // no solve; docs/method.md "Scenes of rigid bodies only").
  const bool sparse = ncp.backend == NcpBackend::sparse ||
                      (ncp.backend == NcpBackend::automatic && nc > ncp.dense_max_contacts);
  if (sparse) {
    cd.G.resize(0, 0);
    if (rigidified) integrator::rigidified_rows(model, data, cd.Ht);  // H_f^T, K_p
    cd.sparse.bind(*data.solver, data.A, rigidified ? data.rigidify.Ht_soft : cd.Ht, h, model.solver);
    // ADMM's per-contact scale from the lumped masses (sparse_delassus.hpp) where A
    // holds them: the dynamic step (A = M + ...), not the static solver's A = K.
    if (model.step.integrator != IntegratorKind::static_equilibrium)
      cd.sparse.set_mass(model.fem.mass_diagonal);
    else
      cd.sparse.clear_mass();
  } else if (rigidified) {
    if (!integrator::rigidified_congruence(model, data, cd.Ht, cd.G)) {
      status.code = StepStatus::Code::solver_failed;
      status.detail = "iterative linear solver did not reach its tolerance (Delassus matrix)";
      return status;
    }
    cd.G *= h;
  } else if (with_rigid && cd.Ht.nonZeros() == 0) {
    cd.G.setZero(3 * nc, 3 * nc);  // only rigid bodies move in these contacts: no soft block
  } else {
    if (!data.solver->inverse_congruence(cd.Ht, cd.G)) {
      status.code = StepStatus::Code::solver_failed;
      status.detail = "iterative linear solver did not reach its tolerance (Delassus matrix)";
      return status;
    }
    cd.G *= h;
  }
  cd.g.noalias() = cd.Ht.transpose() * v;
  // Joint limits: rows of this NCP after the nc contacts (rigid_contact.hpp "limit rows"):
  // on the dense backend rows and columns of G; on the operator columns of the rigid
  // rows Kt (no soft dof: SparseDelassus pads Ht with zero columns for them).
  const int limit_rows = with_rigid ? select_limit_rows(model, data, h, all_limits) : 0;
  if (with_rigid) append_limit_rows(model, data, nc, sparse ? nullptr : &cd.G, cd.g);
  if (with_rigid && sparse) {
    rigid_delassus_rows(model, data, cd.rigid.Kt, cd.g);  // + H_r u_free
  } else if (with_rigid) {
    add_rigid_delassus(model, data, h, cd.G, cd.g);  // + h H_r W_r H_r^T, + H_r u_free
  }
  if (sparse && (with_rigid || rigidified)) {  // + h Kt^T Kt (bodies, limits' rows; parts)
    static const MatX none;
    cd.sparse.set_rigid(with_rigid ? cd.rigid.Kt : none, rigidified ? &data.rigidify.SW : nullptr);
  }
  for (int i = 0; i < nc; ++i) cd.g[3 * i + 2] += cd.contacts.contacts[i].gap / h;
  // static.friction load_step: the tangential slip since the load step's start (set by the
  // static solver after detection, for these contacts; integrator/static_solver.cpp).
  if (cd.slip_offset.size() == 3 * nc) cd.g.head(3 * nc) += cd.slip_offset;
  if (limit_rows > 0) finish_limit_rows(model, data, h, nc, sparse ? nullptr : &cd.G, cd.g);
  data.timings.delassus += seconds_since(t0);

  // Warm start from the last solve's forces of the same contacts (the previous step's,
  // or the previous Newton iteration's).
  t0 = Clock::now();
  cd.lambda.setZero(3 * (nc + limit_rows));
  if (cd.rigid.limit_lambda.size() == num_limit_slots(model))
    for (int l = 0; l < limit_rows; ++l)
      cd.lambda[3 * (nc + l) + 2] = cd.rigid.limit_lambda[cd.rigid.limit_rows[static_cast<std::size_t>(l)].slot];
  for (int i = 0; i < nc; ++i) {
    const collision::Contact::Key key = cd.contacts.contacts[i].key();
    const auto it = std::lower_bound(cd.previous_keys.begin(), cd.previous_keys.end(), key,
                                     [](const auto& entry, const collision::Contact::Key& k) { return entry.first < k; });
    if (it != cd.previous_keys.end() && it->first == key)
      cd.lambda.segment<3>(3 * i) = cd.previous_lambda.segment<3>(3 * it->second);
  }
  const VecX& mu = with_rigid ? cd.rigid.mu_ext : cd.mu;  // (nc + L)
  cd.result = sparse ? cd.solver.solve(cd.sparse, cd.g, mu, ncp, cd.lambda, cd.sigma, cd.modes)
                     : cd.solver.solve(cd.G, cd.g, mu, ncp, cd.lambda, cd.sigma, cd.modes);
  // On the operator the solver forms contact-system matrices as it goes (B's pattern and
  // values, the dense G_W of small sets): booked as the assembly of the contact system
  // (timings.delassus, as G itself on the dense backend), not as NCP time. B's numeric
  // factorizations stay NCP time, as the dense backend's factorizations of G + rho I.
  const double system_seconds = sparse ? cd.sparse.assembly_seconds() : 0.0;
  data.timings.ncp += seconds_since(t0) - system_seconds;
  data.timings.delassus += system_seconds;
  if (sparse && cd.sparse.failed()) {
    status.code = StepStatus::Code::solver_failed;
    status.detail = "iterative linear solver did not reach its tolerance (sparse contact solve)";
    return status;
  }
  for (int k = 0; k < cd.lambda.size(); ++k)
    if (!std::isfinite(cd.lambda[k])) {
      status.code = StepStatus::Code::non_finite;
      status.detail = "contact force of contact " + std::to_string(k / 3) + " is not finite";
      return status;
    }

  // The correction: v_f = v_free + h A^{-1} H^T lambda; the rigid bodies' first: with
  // joint limits, a limit left out of the NCP (far at the start of the step) that the
  // corrected rate crosses makes the solve run again with every limit.
  t0 = Clock::now();
  if (with_rigid) {
    correct_rigid_velocities(model, data, h, cd.lambda);
    if (!all_limits && limit_rows < num_limit_slots(model) && unselected_limit_crossed(model, data, h)) {
      data.timings.correction += seconds_since(t0);
      return solve_contact_problem(model, data, h, v, step_index, true);
    }
  }
  cd.rhs.noalias() = h * (cd.Ht * cd.lambda.head(3 * nc));
  if (rigidified) {
    if (!integrator::solve_rigidified(model, data, cd.rhs, cd.correction)) {
      status.code = StepStatus::Code::solver_failed;
      status.detail = "iterative linear solver did not reach its tolerance (contact correction)";
      return status;
    }
  } else if (with_rigid && cd.Ht.nonZeros() == 0) {
    cd.correction.setZero();  // no soft dof in any contact (rigid bodies only)
  } else if (!data.solver->solve(cd.rhs, cd.correction)) {
    status.code = StepStatus::Code::solver_failed;
    status.detail = "iterative linear solver did not reach its tolerance (contact correction)";
    return status;
  }
  v += cd.correction;
  for (int k = 0; k < v.size(); ++k)
    if (model.fem.fixed[k]) v[k] = 0;
  if (with_rigid) remove_limit_rows(model, data, nc, sparse);

  cd.previous_keys.resize(static_cast<std::size_t>(nc));
  for (int i = 0; i < nc; ++i) cd.previous_keys[i] = {cd.contacts.contacts[i].key(), i};
  std::sort(cd.previous_keys.begin(), cd.previous_keys.end());
  cd.previous_lambda = cd.lambda;
  data.timings.correction += seconds_since(t0);
  return status;
}
}  // namespace

}  // namespace softdiff::contact
