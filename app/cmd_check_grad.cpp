// softdiff check-grad SCENE.yaml: the analytic Jacobian of (x_N, v_N) after N steps
// against central finite differences, block by block (docs/cli.md).
#include "commands.hpp"
#include "common.hpp"
#include "theta.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/parameters.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_rigid.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>

#include <softdiff/core/threads.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <sstream>

namespace softdiff::app {

namespace {

// The rows of J for a state: x (3n), then per rigid body its position and the rotation
// vector (world axes) of its orientation relative to `reference`'s, then v (3n), then per
// rigid body its velocity and angular velocity. (Central differences of these rows are
// the derivatives of the tangent rows forward sensitivities carry: the rotation vector
// of exp(dtheta) q_ref relative to q_ref is dtheta.)
VecX stack(const State& s, const State* reference) {
  const Eigen::Index n3 = s.x.size(), nr = static_cast<Eigen::Index>(s.rigid.size());
  VecX y(2 * (n3 + 6 * nr));
  y.head(n3) = s.x;
  y.segment(n3 + 6 * nr, n3) = s.v.size() ? s.v : VecX::Zero(n3);
  for (Eigen::Index r = 0; r < nr; ++r) {
    const auto& b = s.rigid[static_cast<std::size_t>(r)];
    rigid::RigidState base = b;
    base.orientation = reference ? reference->rigid[static_cast<std::size_t>(r)].orientation : b.orientation;
    base.position.setZero();
    base.velocity.setZero();
    base.angular_velocity.setZero();
    const rigid::Vec12 t = rigid::tangent_between(base, b);
    y.segment<6>(n3 + 6 * r) = t.head<6>();
    y.segment<6>(2 * n3 + 6 * nr + 6 * r) = t.tail<6>();
  }
  return y;
}

// x_N and v_N stacked (6n; with rigid bodies see stack()) after `steps` steps of `model`
// from `initial`; each step (load step) advances `progress`. reference: the state whose
// orientations the rigid rows are measured from (the analytic run's final state).
VecX run(const Model& model, const State& initial, long steps, Progress& progress, const State* reference = nullptr) {
  Data data(model);
  State s = initial, next = initial;
  if (model.step.integrator == IntegratorKind::static_equilibrium) {
    const StepStatus st = integrator::solve_static(model, data, initial, next,
                                                   [&](long, const State&) { progress.advance(); });
    if (!st.ok()) throw ComputationError("a finite-difference run failed: " + describe(model, st));
    if (!next.rigid.empty()) {  // velocities zero: stack's velocity rows
      for (auto& r : next.rigid) r.velocity.setZero(), r.angular_velocity.setZero();
      next.v.setZero(next.x.size());
      return stack(next, reference);
    }
    VecX y = VecX::Zero(2 * next.x.size());
    y.head(next.x.size()) = next.x;
    return y;
  }
  State previous;  // BDF2's history
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::time_step(model, data, s, k > 1 ? &previous : nullptr, next, k);
    if (!st.ok() && st.code != StepStatus::Code::not_converged)
      throw ComputationError("a finite-difference run failed: " + describe(model, st));
    std::swap(previous, s);
    std::swap(s, next);
    progress.advance();
  }
  if (!s.rigid.empty()) return stack(s, reference);
  VecX y(2 * s.x.size());
  y << s.x, s.v;
  return y;
}

// The round-off each row of stack() carries, as a scale S_i (the row's absolute round-off
// is taken as 1e-14 S_i, see run_check_grad). Position rounding is what the velocity rows
// see amplified (measured on configs/rigid_stack.yaml, docs/cli.md "check-grad"): a
// position rounded by one ulp changes a contact's gap term phi / h (and, without contact,
// the elastic force of a stiff body, h A^-1 K dx ~ dx / h) by ulp / h in velocity, and a
// rigid body's angular velocity by that over its lever arm. So, with X the largest
// position coordinate, V the largest velocity, W the largest angular velocity of the
// final state and r the body's radius of gyration sqrt(tr I / 2m):
//   positions X; rotation vectors X / r; velocities V + X / h; angular velocities
//   W + (V + X / h) / r.
VecX round_off_scales(const Model& model, const State& s) {
  const Eigen::Index n3 = s.x.size(), nr = static_cast<Eigen::Index>(s.rigid.size());
  double X = s.x.size() ? s.x.cwiseAbs().maxCoeff() : 0.0, V = s.v.size() ? s.v.cwiseAbs().maxCoeff() : 0.0, W = 0;
  for (const auto& b : s.rigid) {
    X = std::max(X, b.position.cwiseAbs().maxCoeff());
    V = std::max(V, b.velocity.cwiseAbs().maxCoeff());
    W = std::max(W, b.angular_velocity.cwiseAbs().maxCoeff());
  }
  const double h = model.step.integrator == IntegratorKind::static_equilibrium ? 1.0 : model.step.dt;
  VecX S(2 * (n3 + 6 * nr));
  S.head(n3).setConstant(X);
  S.segment(n3 + 6 * nr, n3).setConstant(V + X / h);
  for (Eigen::Index r = 0; r < nr; ++r) {
    const auto& body = model.rigid[static_cast<std::size_t>(r)];
    const double radius = std::sqrt(body.inertia.trace() / (2 * body.mass));
    S.segment<3>(n3 + 6 * r).setConstant(X);
    S.segment<3>(n3 + 6 * r + 3).setConstant(X / radius);
    S.segment<3>(2 * n3 + 6 * nr + 6 * r).setConstant(V + X / h);
    S.segment<3>(2 * n3 + 6 * nr + 6 * r + 3).setConstant(W + (V + X / h) / radius);
  }
  return S;
}

double mean_edge_length(const Model& model) {
  double sum = 0;
  long count = 0;
  for (int e = 0; e < model.fem.num_tets; ++e)
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) {
        sum += (model.fem.X.col(model.fem.tets(a, e)) - model.fem.X.col(model.fem.tets(b, e))).norm();
        ++count;
      }
  if (count) return sum / static_cast<double>(count);
  // A scene of rigid bodies only: their mean radius of gyration sqrt(tr I / 2m) (the 1 m
  // used before made the v0 step 5e-3 m/s on configs/rigid_stack.yaml, 3.6% of the
  // landing speed: v0's error 2.4e-6 dense, 7.1e-6 sparse over 20 steps, the landings'
  // truncation; measured with 0.057 m in docs/cli.md "check-grad").
  for (const auto& b : model.rigid) sum += std::sqrt(b.inertia.trace() / (2 * b.mass)), ++count;
  return count ? sum / static_cast<double>(count) : 1.0;
}

std::string row_name(const Model& model, Eigen::Index row) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes, n6 = 6L * static_cast<Eigen::Index>(model.rigid.size());
  const bool velocity = row >= n3 + n6;
  if (velocity) row -= n3 + n6;
  if (row >= n3) {  // a rigid body's row: position, rotation vector / velocity, angular velocity
    const Eigen::Index k = row - n3;
    return rigid_row_name(model, static_cast<int>(k / 6), static_cast<int>(k % 6), velocity, velocity ? "v" : "x");
  }
  const Eigen::Index dof = row;
  const int node = static_cast<int>(dof / 3);
  std::string body = "?";
  int local = node;
  for (const auto& b : model.fem.bodies)
    if (node >= b.node_begin && node < b.node_begin + b.num_nodes) {
      body = b.name;
      local = node - b.node_begin;
    }
  return std::string(velocity ? "v" : "x") + "[" + body + " node " + std::to_string(local) + "]." + "xyz"[dof % 3];
}

std::string sci(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3e", v);
  return b;
}

}  // namespace

void add_check_grad(CLI::App& app, CheckGradOptions& o) {
  app.add_option("scene", o.scene, "Scene file (YAML, docs/scene.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--wrt", o.wrt,
                 "Blocks to check, comma-separated: young, poisson, density, rayleigh_mass, rayleigh_stiffness, "
                 "actuation, x0, v0, mass, inertia (rigid bodies) (default: all that apply)");
  app.add_option("--steps", o.steps, "Steps of the checked trajectory")->capture_default_str()->check(positive_integer());
  app.add_option("--eps", o.eps,
                 "Relative finite-difference step (times each theta's scale, docs/cli.md)")
      ->capture_default_str()
      ->check(positive_number());
  app.add_option("--tolerance", o.tolerance, "Largest accepted relative error of a block (exit 1 above)")
      ->capture_default_str()
      ->check(positive_number());
  app.add_option("--directions", o.directions, "x0 and v0: random directions checked (seeded)")
      ->capture_default_str()
      ->check(positive_integer());
  app.add_option("--set", o.set, "Override a scene value: KEY=VALUE (repeatable)");
  app.add_option("--threads", o.threads, "OpenMP threads (default: all cores)")->check(CLI::NonNegativeNumber);
  app.add_flag("--json", o.json, "Print the table as one JSON object on stdout");
  app.add_flag("--quiet", o.quiet, "No progress bar");
}

int run_check_grad(const CheckGradOptions& o) {
  set_threads(o.threads);  // the thread plan, core/threads.hpp
  const io::SceneDesc scene = io::load_scene(o.scene, o.set);
  io::BuildReport report;
  Model model = io::build_model(scene, &report);
  for (const auto& w : report.warnings) warn(w);
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  // Finite differences of the equilibrium need it to round-off: the residual criterion
  // (static.tolerance), never the answer criterion's earlier stop (method.md).
  model.step.static_displacement_tolerance = 0;
  std::string wrt = o.wrt;
  if (wrt.empty()) {
    // A static equilibrium depends on neither the damping nor the initial state.
    wrt = is_static ? "young,poisson,density" : "young,poisson,density,rayleigh_mass,rayleigh_stiffness";
    if (model.fem.bodies.empty()) wrt = "";  // a scene of rigid bodies only: no soft parameter
    if (!model.actuation.empty()) wrt += ",actuation";
    if (model.contact.enabled) wrt += ",friction";
    if (!is_static) wrt += ",x0,v0";
    if (!model.rigid.empty()) wrt += ",mass,inertia";
    if (!wrt.empty() && wrt.front() == ',') wrt.erase(0, 1);
  }
  ThetaSelection sel = parse_theta("--wrt", wrt, model);
  const Eigen::Index n3 = 3L * model.fem.num_nodes, nr = static_cast<Eigen::Index>(model.rigid.size());
  // x0 and v0: random directions (max entry 1), seeded; with rigid bodies they also move
  // each rigid body's initial state (6 entries each: see stack()).
  std::mt19937 rng(20261201);
  std::uniform_real_distribution<double> u(-1, 1);
  auto directions = [&]() {
    MatX D(n3 + 6 * nr, o.directions);
    for (Eigen::Index c = 0; c < D.cols(); ++c) {
      for (Eigen::Index r = 0; r < D.rows(); ++r) D(r, c) = u(rng);
      D.col(c) /= D.col(c).cwiseAbs().maxCoeff();
    }
    return D;
  };
  const Eigen::Index rigid_offset_all = sel.layout.rigid_parameter_offset(model);  // before the bases
  if (sel.layout.x0) sel.layout.x0_basis = directions();
  if (sel.layout.v0) sel.layout.v0_basis = directions();
  for (auto& g : sel.groups)
    if (g.name == "x0" || g.name == "v0") {
      g.offset = g.name == "x0" ? sel.layout.x0_offset(model) : sel.layout.v0_offset(model);
      g.size = o.directions;
      g.columns.clear();
      for (int k = 0; k < o.directions; ++k) g.columns.push_back(g.name + " direction " + std::to_string(k));
    } else if (g.name == "mass" || g.name == "inertia") {  // after x0, v0: they moved with the bases
      g.offset += sel.layout.rigid_parameter_offset(model) - rigid_offset_all;
    }

  // Progress on a terminal, in steps (load steps) over every run: the analytic one,
  // then two per column (three for a one-sided difference, counted when met).
  const long run_steps = is_static ? model.step.static_load_steps : o.steps;
  Progress progress(run_steps * (1 + 2 * sel.layout.size(model)), !o.quiet);
  // Analytic: forward sensitivities, or the implicit function theorem at the equilibrium.
  Data data(model);
  State final;
  MatX dx, dv;
  // Smoothed contact derivatives (docs/method.md "A rigid sphere on the soft beam"): with
  // contact and contact.smoothing on (samples > 0, sigma > 0; the default), a contact
  // whose active feature pair is not unique at scale sigma takes the randomized-smoothing
  // estimate, which the finite differences of the exact step need not match. Counted over
  // the analytic run's steps (not available for a static scene: -1).
  const bool smoothing = model.contact.enabled && model.contact.smoothing.samples > 0 &&
                         model.contact.smoothing.sigma > 0;
  long smoothed_contacts = is_static ? -1 : 0;
  long path_sliding = 0, path_slid_sticking = 0;  // static with friction: below
  long path_earlier_load_steps = 0;                // static.friction load_step: below
  const bool load_step_friction = model.step.static_friction == StaticFriction::load_step;
  if (is_static) {
    const StepStatus st =
        integrator::solve_static(model, data, model.initial, final, [&](long, const State&) { progress.advance(); });
    if (!st.ok()) throw ComputationError("the analytic run failed: " + describe(model, st));
    if (const std::string error = diff::static_jacobian(model, data, final, sel.layout, dx); !error.empty())
      throw ComputationError(error);
    dv = MatX::Zero(dx.rows(), dx.cols());
    // Frictional contacts whose tangential state the solver's path decided (docs/method.md
    // "Static equilibrium with contact", *Sliding contacts*; 2026-12-04, branch sgrad): the
    // static solver's friction acts on each Newton increment, so a contact with mu > 0 that
    // slid along the iterates ended where that path left it. The derivative holds its
    // point (sticking) or its slip direction (sliding) at x*; the finite differences of
    // whole solves from the initial state difference the path itself (smooth in theta:
    // on configs/beam_supports_static.yaml the same 2.1e-10 m/Pa at steps 1e-3 to 1e-6
    // and static tolerances 1e-8 and 1e-10), so the two need not agree. Counted with the
    // derivative's own modes (equilibrium_modes): sliding, or sticking after a tangential
    // displacement from the initial state above 1e-9 of the scene's size (the threshold
    // equilibrium_modes takes for a slip; a contact that sticks from the first iterate
    // has none).
    // With static.friction load_step (2026-12-04, branch sfric) each load step's NCP acts
    // on the slip from that load step's start, by construction: no contact is decided by
    // the Newton path. What the derivative does not follow is the start of the last load
    // step (held as given): with several load steps a frictional contact whose points
    // moved tangentially in the earlier ones (from the initial state to the last load
    // step's start, through its frame at x*; the rigid bodies' share included) has a
    // start that depends on theta; counted as path_earlier_load_steps.
    // One pass over the frictional contacts the derivative holds (not breaking), with each
    // one's tangential displacement: since the initial state through H_T under `iterate`,
    // from the initial state to the last load step's start under `load_step`.
    if (model.contact.enabled && !data.contact.contacts.empty() &&
        (!load_step_friction || model.step.static_load_steps > 1)) {
      std::vector<contact::Mode> modes;
      VecX sigma, slip;
      integrator::equilibrium_modes(model, data.contact, final.x,
                                    load_step_friction ? data.static_load_step_start : model.initial.x, modes, sigma);
      if (load_step_friction) {
        VecX initial;
        integrator::extended_positions(model, model.initial.x, model.initial.rigid, initial);
        integrator::contact_slips(data.contact.contacts, initial, data.static_load_step_start_extended, slip);
      } else {
        slip = data.contact.Ht.transpose() * (final.x - model.initial.x);
      }
      double size = 0;
      for (const auto& b : model.fem.bodies) size = std::max(size, b.bbox_diagonal);
      for (int i = 0; i < static_cast<int>(modes.size()); ++i) {
        const contact::Mode mode = modes[static_cast<std::size_t>(i)];
        if (mode == contact::Mode::breaking || data.contact.mu[i] == 0) continue;
        const bool moved = slip.segment<2>(3 * i).norm() > 1e-9 * size;
        if (load_step_friction)
          path_earlier_load_steps += moved;
        else if (mode == contact::Mode::sliding)
          ++path_sliding;
        else
          path_slid_sticking += moved;
      }
    }
  } else {
    // diff::forward_sensitivities' loop, counting the contacts whose geometry derivative
    // was the randomized-smoothing estimate (as simulate --jacobian's smoothed_contacts).
    diff::ForwardSensitivity sensitivity(model, sel.layout);
    State s = model.initial, next = model.initial, previous;
    for (long k = 1; k <= o.steps; ++k) {
      const StepStatus st = integrator::time_step(model, data, s, k > 1 ? &previous : nullptr, next, k);
      if (!st.ok()) throw ComputationError("the analytic run failed: " + describe(model, st));
      if (!sensitivity.advance(model, data, s, next))
        throw ComputationError("the analytic run failed: the derivative of step " + std::to_string(k) +
                               " failed (a linear solve did not succeed or produced non-finite values)");
      if (model.contact.enabled && !data.contact.contacts.empty())
        smoothed_contacts += sensitivity.step().smoothed_contacts();
      std::swap(previous, s);
      std::swap(s, next);
      progress.advance();
    }
    final = s;
    dx = sensitivity.dx_dtheta();
    dv = sensitivity.dv_dtheta();
  }
  MatX J(2 * dx.rows(), dx.cols());
  J << dx, dv;
  // Fault injection, for the tests only (docs/cli.md): SOFTDIFF_CHECK_GRAD_FAULT=THETA:FACTOR
  // multiplies the analytic columns of block THETA by FACTOR, a wrong derivative that the
  // comparison must report (tests/app/test_cli_rigid_derivatives.cpp).
  if (const char* fault = std::getenv("SOFTDIFF_CHECK_GRAD_FAULT")) {
    const std::string f = fault;
    const auto colon = f.find(':');
    bool applied = false;
    char* end = nullptr;
    const double factor = colon == std::string::npos ? 0.0 : std::strtod(f.c_str() + colon + 1, &end);
    if (colon != std::string::npos && end && *end == '\0' && end != f.c_str() + colon + 1)
      for (const auto& g : sel.groups)
        if (g.name == f.substr(0, colon)) J.middleCols(g.offset, g.size) *= factor, applied = true;
    if (!applied)
      throw InputError("SOFTDIFF_CHECK_GRAD_FAULT: '" + f + "' is not THETA:FACTOR with THETA a checked block");
    warn("SOFTDIFF_CHECK_GRAD_FAULT: the analytic block '" + f.substr(0, colon) + "' is multiplied by " +
         f.substr(colon + 1) + " (a fault injected for the tests)");
  }

  // Finite differences, column by column.
  const double h = model.step.dt, edge = mean_edge_length(model);
  MatX J_fd(J.rows(), J.cols());
  // Round-off of each finite-difference column: each row of the runs' outputs carries
  // ~1e-14 of its round-off scale (round_off_scales: 1e-14, measured as cond(A) eps over a
  // few steps on the soft scenes; the scales, measured on rigid_stack), divided by the
  // step 2e. Before 2026-12-04 the scale was the output's norm alone, which the velocity
  // rows' round-off (position round-off / h, over the lever arm for angular velocities)
  // exceeded: on rigid_stack.yaml the zero blocks' differences (1.7e-13 rad/s / 2e) failed.
  const double round_off = 1e-14 * round_off_scales(model, final).norm();  // of one run's output (the analytic run's scales)
  VecX noise(J.cols());
  const Eigen::Index np = sel.layout.actuation_offset();
  const Eigen::Index na = sel.layout.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
  const Eigen::Index rp0 = sel.layout.rigid_parameter_offset(model);
  const State* ref = nr ? &final : nullptr;  // the rigid rows' orientations are measured from the analytic run's
  for (Eigen::Index c = 0; c < J.cols(); ++c) {
    Model mp = model, mm = model;
    State sp = model.initial, sm = model.initial;
    double e = 0;
    if (c < np) {
      const ParameterId id = sel.layout.parameters[static_cast<std::size_t>(c)];
      const double value = diff::get_parameter(model, id);
      double scale = std::abs(value);
      if (id.kind == Parameter::poisson) scale = std::max(scale, 0.1);
      if (id.kind == Parameter::rayleigh_mass) scale = std::max(scale, 1 / h);  // h alpha ~ 1: damping matters
      if (id.kind == Parameter::rayleigh_stiffness) scale = std::max(scale, h);    // h beta ~ h^2
      if (id.kind == Parameter::friction) scale = std::max(scale, 0.1);
      e = o.eps * scale;
      if ((id.kind == Parameter::rayleigh_mass || id.kind == Parameter::rayleigh_stiffness ||
           id.kind == Parameter::friction) && value - e < 0) {
        // At the bound (no damping): the one-sided second-order difference
        // (-3 f(p) + 4 f(p + e) - f(p + 2e)) / 2e, as accurate as the central one.
        Model m2 = model;
        diff::set_parameter(mp, id, value + e);
        diff::set_parameter(m2, id, value + 2 * e);
        progress.set_total(progress.total() + run_steps);
        J_fd.col(c) = (-3 * run(model, sp, o.steps, progress, ref) + 4 * run(mp, sp, o.steps, progress, ref) -
                       run(m2, sp, o.steps, progress, ref)) / (2 * e);
        noise[c] = 4 * round_off / (2 * e);  // |-3| + 4 + |-1| = 8 runs' round-offs where the central has 2
        continue;
      }
      diff::set_parameter(mp, id, value + e);
      diff::set_parameter(mm, id, value - e);
    } else if (c < np + na) {
      const int a = static_cast<int>(c - np);
      const auto& v = model.actuation.actuators[static_cast<std::size_t>(a)].value;
      double scale = std::max(std::abs(v.constant), 1.0);
      for (const auto& pt : v.points) scale = std::max(scale, std::abs(pt[1]));
      e = o.eps * scale;
      diff::offset_actuator(mp, a, e);
      diff::offset_actuator(mm, a, -e);
    } else if (c >= rp0) {
      // A rigid body's mass (scale: its value) or inertia component (scale: the trace / 3,
      // the off-diagonal components being 0 or small): eps times it.
      const auto& p = sel.layout.rigid_parameters[static_cast<std::size_t>(c - rp0)];
      auto& body = model.rigid[static_cast<std::size_t>(p.body)];
      const double value = rigid::get_parameter(body, p.index);
      e = o.eps * (p.index == 0 ? std::abs(value) : body.inertia.trace() / 3);
      rigid::set_parameter(mp.rigid[static_cast<std::size_t>(p.body)], p.index, value + e);
      rigid::set_parameter(mm.rigid[static_cast<std::size_t>(p.body)], p.index, value - e);
    } else {
      const bool is_x = sel.layout.x0 && c < sel.layout.v0_offset(model);
      const Eigen::Index k = c - (is_x ? sel.layout.x0_offset(model) : sel.layout.v0_offset(model));
      const VecX d = (is_x ? sel.layout.x0_basis : sel.layout.v0_basis).col(k);
      // x0: a hundredth of the mean edge length L (the response to positions is
      // nonlinear on the scale of the elements' strains, far below an edge); v0: a
      // tenth of L per step (the first step is affine in v0, so only round-off limits
      // it). Measured on the shipped beam, finger and trunk (docs/cli.md).
      // A scene of rigid bodies only (no element to strain; L their mean radius of
      // gyration, mean_edge_length): x0 E times L itself.
      e = o.eps * (is_x ? (model.fem.num_tets > 0 ? 0.01 : 1.0) * edge : 0.1 * edge / h);
      // (Rigid bodies: the same steps on their 6 entries, a rotation by e dtheta in world axes.)
      (is_x ? sp.x : sp.v) += e * d.head(n3);
      (is_x ? sm.x : sm.v) -= e * d.head(n3);
      for (Eigen::Index r = 0; r < nr; ++r) {
        rigid::Vec12 t = rigid::Vec12::Zero();
        t.segment<6>(is_x ? 0 : 6) = d.segment<6>(n3 + 6 * r);
        auto& bp = sp.rigid[static_cast<std::size_t>(r)];
        auto& bm = sm.rigid[static_cast<std::size_t>(r)];
        bp = rigid::retract(bp, t, e);
        bm = rigid::retract(bm, t, -e);
      }
    }
    J_fd.col(c) = (run(mp, sp, o.steps, progress, ref) - run(mm, sm, o.steps, progress, ref)) / (2 * e);
    noise[c] = round_off / (2 * e);
  }

  progress.finish();

  // The table.
  bool passed = true, any_path_dependent = false;
  const bool path_dependent = is_static && path_sliding + path_slid_sticking + path_earlier_load_steps > 0;
  Json j;
  j.begin_object();
  j.value("command", "check-grad").value("scene", o.scene).value("steps", o.steps).value("eps", o.eps);
  j.value("tolerance", o.tolerance);
  j.begin_array("blocks");
  std::ostringstream table;
  if (is_static)
    table << "d x*/d theta at the static equilibrium, central differences with eps " << o.eps << "\n";
  else
    table << "d(x_N, v_N)/d theta after " << o.steps << " step(s), central differences with eps " << o.eps << "\n";
  char line[512];
  std::snprintf(line, sizeof line, "%-20s %7s %11s %10s  %s\n", "theta", "columns", "rel. error", "round-off",
                "worst entry: analytic vs finite differences");
  table << line;
  for (const auto& g : sel.groups) {
    const MatX A = J.middleCols(g.offset, g.size), F = J_fd.middleCols(g.offset, g.size);
    // A block that is zero (e.g. friction with sticking contacts) is compared with the
    // differences' round-off: both within it is a match, not a relative error of noise.
    // The round-off is printed relative to ||J_fd|| (the smallest relative error the
    // differences resolve) and, for such a zero block, as the bound itself.
    const double floor = noise.segment(g.offset, g.size).norm();
    const double denom = F.norm();
    const bool zero_block = A.norm() <= floor && denom <= floor;
    const std::string resolution = denom > 0 ? sci(floor / denom) : std::string("-");
    const double rel = zero_block ? 0.0 : denom > 0 ? (A - F).norm() / denom : (A - F).norm();
    Eigen::Index row = 0, col = 0;
    (A - F).cwiseAbs().maxCoeff(&row, &col);
    const bool ok = rel <= o.tolerance && std::isfinite(rel);
    passed = passed && ok;
    const bool block_path_dependent = !ok && path_dependent;
    any_path_dependent = any_path_dependent || block_path_dependent;
    std::snprintf(line, sizeof line, "%-20s %7ld %11s %10s  %s, %s: %s vs %s%s%s\n", g.name.c_str(),
                  static_cast<long>(g.size), sci(rel).c_str(), resolution.c_str(), row_name(model, row).c_str(),
                  g.columns[static_cast<std::size_t>(col)].c_str(), sci(A(row, col)).c_str(), sci(F(row, col)).c_str(),
                  zero_block ? ("   (zero: both within the round-off " + sci(floor) + ")").c_str() : "",
                  ok ? "" : block_path_dependent ? "   ABOVE TOLERANCE (path-dependent, see below)" : "   ABOVE TOLERANCE");
    table << line;
    j.begin_object()
        .value("theta", g.name)
        .value("columns", static_cast<long>(g.size))
        .value("rel_error", rel)
        .value("worst_row", row_name(model, row))
        .value("worst_column", g.columns[static_cast<std::size_t>(col)])
        .value("analytic", A(row, col))
        .value("fd", F(row, col))
        .value("round_off", floor)
        .value("zero_within_round_off", zero_block)
        .value("passed", ok)
        .value("path_dependent", block_path_dependent)
        .end_object();
  }
  j.end_array();
  j.value("passed", passed);
  if (is_static)
    j.begin_object("path_dependent_contacts")
        .value("sliding", path_sliding)
        .value("stuck_after_sliding", path_slid_sticking)
        .value("static_friction", load_step_friction ? "load_step" : "iterate")
        .value("moved_in_earlier_load_steps", path_earlier_load_steps)
        .end_object();
  j.value("smoothed_contact_derivatives", smoothing);
  j.begin_object("contact_smoothing")
      .value("samples", smoothing ? model.contact.smoothing.samples : 0)
      .value("sigma", smoothing ? model.contact.smoothing.sigma : 0.0)
      .value("smoothed_contacts", smoothing ? smoothed_contacts : 0L)
      .end_object();
  j.end_object();
  std::string smoothing_line = "contact derivatives: ";
  if (!model.contact.enabled)
    smoothing_line += "no contact";
  else if (!smoothing)
    smoothing_line += "exact (contact.smoothing off)";
  else
    smoothing_line += "randomized smoothing where a feature pair is not unique (samples " +
                      std::to_string(model.contact.smoothing.samples) + ", sigma " +
                      sci(model.contact.smoothing.sigma) + " m)" +
                      (is_static ? std::string()
                                 : ": " + std::to_string(smoothed_contacts) +
                                       " smoothed contact(s) over the analytic run's steps");
  table << smoothing_line << "\n";
  if (is_static && model.contact.enabled && load_step_friction)
    table << "frictional contacts: slip from the load step's start (static.friction load_step), "
          << path_earlier_load_steps << " moved in earlier load steps" << (path_dependent ? " (path-dependent)" : "")
          << "\n";
  else if (is_static && model.contact.enabled)
    table << "frictional contacts decided by the solver's path: " << path_sliding << " sliding, "
          << path_slid_sticking << " stuck after sliding" << (path_dependent ? " (path-dependent)" : "") << "\n";
  if (o.json)
    std::printf("%s\n", j.str().c_str());
  else
    std::printf("%s", table.str().c_str());
  // A failure that the smoothing can explain: say so (static: the count is unknown).
  if (!passed && smoothing && smoothed_contacts != 0 && !any_path_dependent)
    warn(std::string(is_static ? "the analytic run may have used smoothed contact derivatives (contact.smoothing on; "
                                 "a static scene's derivative does not count them)"
                               : "the analytic run used smoothed contact derivatives (" +
                                     std::to_string(smoothed_contacts) + " smoothed contact(s))") +
         ", which can fail near a contact feature boundary by design; to check the exact derivative, rerun with "
         "--set contact.smoothing.samples=0 (docs/cli.md \"check-grad\")");
  if (any_path_dependent && load_step_friction)
    error("the static equilibrium with friction depends on the earlier load steps here: " +
          std::to_string(path_earlier_load_steps) +
          " frictional contact(s) moved tangentially before the last load step, whose start the derivative holds "
          "as given (static.friction load_step), so the finite differences of whole solves measure how that start "
          "changes with theta as well; a block above the tolerance here is not a verdict on the derivative (one load "
          "step, static.load_steps: 1, has none; docs/method.md \"Static equilibrium with contact\", docs/cli.md "
          "\"check-grad\")");
  else if (any_path_dependent)
    error("the static equilibrium with friction is path-dependent here: " + std::to_string(path_sliding) +
          " contact(s) slide and " + std::to_string(path_slid_sticking) +
          " stick after sliding along the solver's Newton iterates, so the finite differences of whole solves "
          "measure how that path changes with theta, not the derivative at the equilibrium (which holds those "
          "contacts' points and slip directions); a block above the tolerance here is not a verdict on the "
          "derivative, which check-grad cannot check on this scene (issue 21; docs/method.md \"Static equilibrium "
          "with contact\", docs/cli.md \"check-grad\")");
  if (!passed) error("some blocks are above the tolerance " + sci(o.tolerance));
  return passed ? kExitOk : kExitFailed;
}

}  // namespace softdiff::app
