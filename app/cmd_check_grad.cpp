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
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>

#include <softdiff/core/threads.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <sstream>

namespace softdiff::app {

namespace {

// x_N and v_N stacked (6n) after `steps` steps of `model` from `initial`; each step
// (load step) advances `progress`.
VecX run(const Model& model, const State& initial, long steps, Progress& progress) {
  Data data(model);
  State s = initial, next = initial;
  if (model.step.integrator == IntegratorKind::static_equilibrium) {
    const StepStatus st = integrator::solve_static(model, data, initial, next,
                                                   [&](long, const State&) { progress.advance(); });
    if (!st.ok()) throw ComputationError("a finite-difference run failed: " + describe(model, st));
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
  VecX y(2 * s.x.size());
  y << s.x, s.v;
  return y;
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
  return count ? sum / static_cast<double>(count) : 1.0;
}

std::string row_name(const Model& model, Eigen::Index row) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes;
  const bool velocity = row >= n3;
  const Eigen::Index dof = velocity ? row - n3 : row;
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
                 "actuation, x0, v0 (default: all that apply)");
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
  demand_no_rigid_bodies("check-grad", model);
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  // Finite differences of the equilibrium need it to round-off: the residual criterion
  // (static.tolerance), never the answer criterion's earlier stop (method.md).
  model.step.static_displacement_tolerance = 0;
  std::string wrt = o.wrt;
  if (wrt.empty()) {
    // A static equilibrium depends on neither the damping nor the initial state.
    wrt = is_static ? "young,poisson,density" : "young,poisson,density,rayleigh_mass,rayleigh_stiffness";
    if (!model.actuation.empty()) wrt += ",actuation";
    if (model.contact.enabled) wrt += ",friction";
    if (!is_static) wrt += ",x0,v0";
  }
  ThetaSelection sel = parse_theta("--wrt", wrt, model);
  const Eigen::Index n3 = 3L * model.fem.num_nodes;
  // x0 and v0: random directions (max entry 1), seeded.
  std::mt19937 rng(20261201);
  std::uniform_real_distribution<double> u(-1, 1);
  auto directions = [&]() {
    MatX D(n3, o.directions);
    for (Eigen::Index c = 0; c < D.cols(); ++c) {
      for (Eigen::Index r = 0; r < n3; ++r) D(r, c) = u(rng);
      D.col(c) /= D.col(c).cwiseAbs().maxCoeff();
    }
    return D;
  };
  if (sel.layout.x0) sel.layout.x0_basis = directions();
  if (sel.layout.v0) sel.layout.v0_basis = directions();
  for (auto& g : sel.groups)
    if (g.name == "x0" || g.name == "v0") {
      g.offset = g.name == "x0" ? sel.layout.x0_offset(model) : sel.layout.v0_offset(model);
      g.size = o.directions;
      g.columns.clear();
      for (int k = 0; k < o.directions; ++k) g.columns.push_back(g.name + " direction " + std::to_string(k));
    }

  // Progress on a terminal, in steps (load steps) over every run: the analytic one,
  // then two per column (three for a one-sided difference, counted when met).
  const long run_steps = is_static ? model.step.static_load_steps : o.steps;
  Progress progress(run_steps * (1 + 2 * sel.layout.size(model)), !o.quiet);
  // Analytic: forward sensitivities, or the implicit function theorem at the equilibrium.
  Data data(model);
  State final;
  MatX dx, dv;
  if (is_static) {
    const StepStatus st =
        integrator::solve_static(model, data, model.initial, final, [&](long, const State&) { progress.advance(); });
    if (!st.ok()) throw ComputationError("the analytic run failed: " + describe(model, st));
    if (!integrator::static_sensitivities(model, data, final, {sel.layout.parameters, sel.layout.actuation}, dx))
      throw ComputationError("the derivative of the equilibrium failed");
    dv = MatX::Zero(dx.rows(), dx.cols());
  } else {
    const StepStatus st = diff::forward_sensitivities(model, data, model.initial, o.steps, sel.layout, final, dx, dv);
    if (!st.ok()) throw ComputationError("the analytic run failed: " + describe(model, st));
    progress.advance(o.steps);
  }
  MatX J(2 * n3, dx.cols());
  J << dx, dv;

  // Finite differences, column by column.
  const double h = model.step.dt, edge = mean_edge_length(model);
  MatX J_fd(J.rows(), J.cols());
  // Round-off of each finite-difference column: the runs' outputs carry ~1e-14 of their
  // size (measured: cond(A) eps over a few steps), divided by the step 2e.
  const double output_size = std::sqrt(final.x.squaredNorm() + final.v.squaredNorm());  // the analytic run's
  VecX noise(J.cols());
  const Eigen::Index np = sel.layout.actuation_offset();
  const Eigen::Index na = sel.layout.actuation ? static_cast<Eigen::Index>(model.actuation.actuators.size()) : 0;
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
        J_fd.col(c) = (-3 * run(model, sp, o.steps, progress) + 4 * run(mp, sp, o.steps, progress) -
                       run(m2, sp, o.steps, progress)) / (2 * e);
        noise[c] = 1e-14 * output_size / (2 * e);
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
    } else {
      const bool is_x = sel.layout.x0 && c < sel.layout.v0_offset(model);
      const Eigen::Index k = c - (is_x ? sel.layout.x0_offset(model) : sel.layout.v0_offset(model));
      const VecX d = (is_x ? sel.layout.x0_basis : sel.layout.v0_basis).col(k);
      // x0: a hundredth of the mean edge length L (the response to positions is
      // nonlinear on the scale of the elements' strains, far below an edge); v0: a
      // tenth of L per step (the first step is affine in v0, so only round-off limits
      // it). Measured on the shipped beam, finger and trunk (docs/cli.md).
      e = o.eps * (is_x ? 0.01 * edge : 0.1 * edge / h);
      (is_x ? sp.x : sp.v) += e * d;
      (is_x ? sm.x : sm.v) -= e * d;
    }
    J_fd.col(c) = (run(mp, sp, o.steps, progress) - run(mm, sm, o.steps, progress)) / (2 * e);
    noise[c] = 1e-14 * output_size / (2 * e);
  }

  progress.finish();

  // The table.
  bool passed = true;
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
  std::snprintf(line, sizeof line, "%-20s %7s %11s  %s\n", "theta", "columns", "rel. error",
                "worst entry: analytic vs finite differences");
  table << line;
  for (const auto& g : sel.groups) {
    const MatX A = J.middleCols(g.offset, g.size), F = J_fd.middleCols(g.offset, g.size);
    // A block that is zero (e.g. friction with sticking contacts) is compared with the
    // differences' round-off: both within it is a match, not a relative error of noise.
    const double floor = noise.segment(g.offset, g.size).norm();
    const double denom = F.norm();
    const bool zero_block = A.norm() <= floor && denom <= floor;
    const double rel = zero_block ? 0.0 : denom > 0 ? (A - F).norm() / denom : (A - F).norm();
    Eigen::Index row = 0, col = 0;
    (A - F).cwiseAbs().maxCoeff(&row, &col);
    const bool ok = rel <= o.tolerance && std::isfinite(rel);
    passed = passed && ok;
    std::snprintf(line, sizeof line, "%-20s %7ld %11s  %s, %s: %s vs %s%s\n", g.name.c_str(), static_cast<long>(g.size),
                  sci(rel).c_str(), row_name(model, row).c_str(), g.columns[static_cast<std::size_t>(col)].c_str(),
                  sci(A(row, col)).c_str(), sci(F(row, col)).c_str(), ok ? "" : "   ABOVE TOLERANCE");
    table << line;
    j.begin_object()
        .value("theta", g.name)
        .value("columns", static_cast<long>(g.size))
        .value("rel_error", rel)
        .value("worst_row", row_name(model, row))
        .value("worst_column", g.columns[static_cast<std::size_t>(col)])
        .value("analytic", A(row, col))
        .value("fd", F(row, col))
        .value("passed", ok)
        .end_object();
  }
  j.end_array();
  j.value("passed", passed);
  j.end_object();
  if (o.json)
    std::printf("%s\n", j.str().c_str());
  else
    std::printf("%s", table.str().c_str());
  if (!passed) error("some blocks are above the tolerance " + sci(o.tolerance));
  return passed ? kExitOk : kExitFailed;
}

}  // namespace softdiff::app
