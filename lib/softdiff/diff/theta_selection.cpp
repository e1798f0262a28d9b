#include <softdiff/diff/theta_selection.hpp>

#include <softdiff/core/error.hpp>
#include <softdiff/core/text.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>

#include <sstream>
#include <variant>

namespace softdiff::diff {

namespace {


// A scene of rigid bodies only (no soft node) steps without the soft stage
// (integrator/bdf2.cpp time_step_rigid_only) and is differentiated without it
// (implicit_euler_derivatives.cpp: an empty soft system, the rigid rows alone; docs/method.md
// "Scenes of rigid bodies only"); its static case is refused below.
void demand_differentiable(const std::string& option, const Model& model) {
  // Rigidified parts (issue 21 item 4 for item 2; integrator/rigidify_derivatives.hpp):
  // implicit Euler and BDF2 (rigidify_bdf2_derivatives.hpp), Newton (newton_iterations > 1,
  // rnewtp), with or without contact on either backend (dense: the record's G; sparse: the
  // operator's rows H_f^T and K_p, rpsp; Newton: those rows at the converged tangent), with
  // rigid bodies in contact beside them on both backends and under Newton (rpint: dense;
  // rpsn: sparse and Newton, the bodies' rows L_r^T H_r^T beside the parts'), a limited
  // joint in contact included on both backends and under Newton (rplim: the joint limits'
  // extended system carries the parts' rows, contact/rigid_contact_derivatives.hpp).
  // Static (2026-12-04, rstat; integrator/static_solver_derivatives.cpp, docs/method.md
  // "Static equilibrium with rigidified parts", *Derivatives*): the reduced equilibrium,
  // with or without contact, free and translation-servo parts; since rstp (2026-12-04)
  // also with a cable through a part (its stiffness in the parts' coupling), beside rigid
  // bodies (hinges, sliders, fixed bodies; a free body beside soft bodies is refused
  // below as without parts) and on a body held by contact alone (its proximal term in
  // the parts' coupling). Every integrator is differentiated with parts.
  // BDF2 with rigid bodies (rigid/rigid_bdf2_derivatives.hpp): differentiated as implicit
  // Euler is, with and without contact; with a limited joint in contact each step through
  // the branch it recorded (integrator/bdf2.cpp: BDF2, or the restart as the implicit Euler
  // contact step from s_n, data.history_weight 0), as implicit Euler's limits (the
  // finite-difference tests of that case run on the dense backend).
  // Issue 21, item 4: the rigid step is differentiated with and without contact, a
  // joint limit's rows in the contact solve included (contact/rigid_contact_derivatives.hpp):
  // on the dense backend the extended G (prepare_limits), on the sparse one the extended
  // rigid rows Kt on the operator (rpsp). Newton with rigid bodies in contact (docs/method.md
  // "Newton with rigid contact") is differentiated on both backends (with joint limits in
  // contact, the contacts' G with the converged tangent in the extended G). (A scene of
  // rigid bodies only has no Newton: its step is linear in the contact impulse.)
  if (model.step.integrator == IntegratorKind::static_equilibrium) {
    // Static with rigid bodies (integrator/static_solver_derivatives.hpp, the rigid
    // equations in the implicit function theorem): hinged, slider and fixed bodies, beside
    // soft bodies or alone, joint limits (an active one holds its body), free bodies in a
    // scene of rigid bodies only, and frictionless free bodies beside soft bodies (held in
    // all six dofs by their contacts at the equilibrium: checked there, 2026-12-04, srfree);
    // a free body with friction beside soft bodies is not differentiated yet (with
    // static.friction iterate its tangential state is the solver's path; with load_step it
    // is a function of the parameters, but its derivative is not unique where redundant
    // contact records slide: docs/method.md *Load-step-anchored friction*, *Found*).
    const int soft_bodies = static_cast<int>(model.fem.bodies.size());
    for (std::size_t r = 0; r < model.rigid.size(); ++r) {
      const auto& b = model.rigid[r];
      if (b.joint.kind != rigid::Joint::Kind::free || model.fem.num_nodes == 0) continue;
      const double mu = model.contact.detection.max_friction(soft_bodies + static_cast<int>(r));
      if (mu > 0) {
        std::ostringstream friction;
        friction << mu;
        throw InputError(option + ": derivatives of a static scene with a free rigid body in frictional contact "
                                  "beside soft bodies are not supported yet (issue 21; rigid body '" + b.name +
                                  "'): with friction (" + friction.str() +
                                  ") its static tangential state is the stick accumulated along the solver's path "
                                  "(static.friction: iterate), or, with static.friction: load_step, a function of "
                                  "the parameters whose derivative is not validated yet (it is not unique where "
                                  "redundant contact records slide: docs/method.md \"Static equilibrium with "
                                  "contact\", *Found*); frictionless free bodies "
                                  "held in all six dofs by their contacts, hinged, slider and fixed bodies are "
                                  "differentiated");
      }
    }
    for (const auto& b : model.fem.bodies)
      if (b.psd_projection)
        throw InputError(option + ": a static scene with psd_projection (body '" + b.name +
                         "') is not differentiated in this version");
    for (const auto& a : model.actuation.actuators) {
      const auto* servo = std::get_if<actuation::Servo>(&a.kind);
      if (!std::holds_alternative<actuation::Cable>(a.kind) && !(servo && !servo->is_rotation()))
        throw InputError(option + ": a static scene with actuator '" + a.name + "' (" + a.kind_name() +
                         ") is not differentiated in this version (cables and translation servos are)");
    }
  }
  if (model.step.newton_iterations > 1)
    for (const auto& b : model.fem.bodies)
      if (b.psd_projection)
        throw InputError(option + ": newton_iterations > 1 with psd_projection (body '" + b.name +
                         "') is not differentiated in this version (either alone is)");
}

}  // namespace

std::string rigid_row_name(const Model& model, int body, int k, bool velocity, const std::string& prefix) {
  static const char* x_rows[6] = {"x", "y", "z", "rx", "ry", "rz"};
  static const char* v_rows[6] = {"vx", "vy", "vz", "wx", "wy", "wz"};
  return prefix + "[" + model.rigid[static_cast<std::size_t>(body)].name + "]." + (velocity ? v_rows : x_rows)[k];
}

ThetaSelection parse_theta(const std::string& option, const std::string& list, const Model& model) {
  const std::vector<std::string> names = split_list(list);
  const std::string valid = "young, poisson, density, rayleigh_mass, rayleigh_stiffness, actuation, x0, v0, mass, inertia";
  if (names.empty()) throw InputError(option + ": expected a comma-separated list of " + valid + "; got nothing");
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (names[i].empty()) throw InputError(option + " " + list + ": empty name in the list (expected " + valid + ")");
    for (std::size_t j = 0; j < i; ++j)
      if (names[j] == names[i]) throw InputError(option + " " + list + ": '" + names[i] + "' is listed twice");
  }
  demand_differentiable(option, model);
  ThetaSelection sel;
  // Layout order is fixed (parameters, actuation, x0, v0); groups keep the given order.
  std::vector<std::string> params_given;
  for (const auto& n : names) {
    if (n == "actuation") {
      if (model.actuation.actuators.empty())
        throw InputError(option + ": 'actuation' needs actuators, and this scene has none");
      sel.layout.actuation = true;
    } else if ((n == "x0" || n == "v0") && model.step.integrator == IntegratorKind::static_equilibrium) {
      throw InputError(option + ": '" + n + "' has no effect on a static equilibrium (it does not depend on the "
                                             "initial state); differentiate with respect to parameters or actuation");
    } else if (n == "x0") {
      sel.layout.x0 = true;
    } else if (n == "v0") {
      sel.layout.v0 = true;
    } else if (n == "mass" || n == "inertia") {
      // Rigid bodies' parameters (issue 21): mass, one column per rigid body; inertia, six
      // per rigid body (body axes: xx, yy, zz, xy, xz, yz); their columns come last.
      if (model.rigid.empty()) throw InputError(option + ": '" + n + "' needs rigid bodies, and this scene has none");
    } else if (const auto p = parse_parameter(n)) {
      if (*p == Parameter::friction) {
        // One column per contact pair rule (its coefficient).
        if (!model.contact.enabled || model.contact.detection.pairs.empty())
          throw InputError(option + ": 'friction' needs contact, and this scene has none");
        for (int r = 0; r < static_cast<int>(model.contact.detection.pairs.size()); ++r)
          sel.layout.parameters.push_back({*p, r});
      } else {
        if (model.fem.bodies.empty())  // a scene of rigid bodies only: its parameters are mass, inertia
          throw InputError(option + ": '" + n + "' needs soft bodies, and this scene has none (rigid bodies only: "
                                             "mass, inertia, x0, v0" + (model.contact.enabled ? ", friction" : "") + ")");
        for (int b = 0; b < static_cast<int>(model.fem.bodies.size()); ++b) sel.layout.parameters.push_back({*p, b});
      }
      params_given.push_back(n);
    } else {
      throw InputError(option + " " + list + ": unknown name '" + n + "' (expected one of " + valid + ")");
    }
  }
  const int nr = static_cast<int>(model.rigid.size());
  std::vector<std::string> rigid_given;
  for (const auto& n : names)
    if (n == "mass" || n == "inertia") {
      for (int r = 0; r < nr; ++r)
        if (n == "mass")
          sel.layout.rigid_parameters.push_back({r, 0});
        else
          for (int k = 1; k < rigid::kRigidParameters; ++k) sel.layout.rigid_parameters.push_back({r, k});
      rigid_given.push_back(n);
    }
  const Eigen::Index nb = static_cast<Eigen::Index>(model.fem.bodies.size());
  const Eigen::Index n3 = 3L * model.fem.num_nodes;
  for (const auto& n : names) {
    ThetaGroup g;
    g.name = n;
    if (n == "actuation") {
      g.offset = sel.layout.actuation_offset();
      g.size = static_cast<Eigen::Index>(model.actuation.actuators.size());
      for (const auto& a : model.actuation.actuators) g.columns.push_back("actuation[" + a.name + "]");
    } else if (n == "x0" || n == "v0") {
      g.offset = n == "x0" ? sel.layout.x0_offset(model) : sel.layout.v0_offset(model);
      g.size = n3 + 6L * nr;
      for (Eigen::Index k = 0; k < n3; ++k) g.columns.push_back(n + "[" + std::to_string(k) + "]");
      // Rigid bodies: position and rotation vector (x0), velocity and angular velocity (v0).
      for (int r = 0; r < nr; ++r)
        for (int k = 0; k < 6; ++k) g.columns.push_back(rigid_row_name(model, r, k, n == "v0", n));
    } else if (n == "mass" || n == "inertia") {
      g.offset = sel.layout.rigid_parameter_offset(model);
      for (const auto& before : rigid_given) {
        if (before == n) break;
        g.offset += before == "mass" ? nr : 6L * nr;
      }
      g.size = n == "mass" ? nr : 6L * nr;
      const auto all = sel.layout.column_names(model);
      const Eigen::Index first_rigid = static_cast<Eigen::Index>(all.size()) - static_cast<Eigen::Index>(sel.layout.rigid_parameters.size());
      for (Eigen::Index k = 0; k < g.size; ++k)
        g.columns.push_back(all[static_cast<std::size_t>(first_rigid + g.offset - sel.layout.rigid_parameter_offset(model) + k)]);
    } else {
      // The parameters' columns, in the order given: friction has one per pair rule.
      const auto columns_of = [&](const std::string& name) {
        return name == "friction" ? static_cast<Eigen::Index>(model.contact.detection.pairs.size()) : nb;
      };
      g.offset = 0;
      for (const auto& before : params_given) {
        if (before == n) break;
        g.offset += columns_of(before);
      }
      g.size = columns_of(n);
      const auto all = sel.layout.column_names(model);
      for (Eigen::Index k = 0; k < g.size; ++k) g.columns.push_back(all[static_cast<std::size_t>(g.offset + k)]);
    }
    sel.groups.push_back(std::move(g));
  }
  return sel;
}

std::string static_jacobian(const Model& model, Data& data, const State& equilibrium, const ThetaLayout& layout,
                            MatX& dx_dtheta) {
  integrator::StaticTheta theta{layout.parameters, layout.actuation, {}};
  for (const auto& id : layout.rigid_parameters) theta.rigid_parameters.emplace_back(id.body, id.index);
  try {
    if (integrator::static_sensitivities(model, data, equilibrium, theta, dx_dtheta)) return {};
  } catch (const ComputationError& e) {
    return std::string("the derivative of the equilibrium failed: ") + e.what();
  }
  return "the derivative of the equilibrium failed (inverted element or tangent not positive definite)";
}

}  // namespace softdiff::diff
