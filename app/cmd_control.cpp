// softdiff control SCENE.yaml: inverse dynamics, driving an effector to a goal by
// the per-step QP on the actuation change (docs/cli.md; optim/control.hpp).
#include "commands.hpp"
#include "common.hpp"
#include "theta.hpp"
#include "units.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/core/timer.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/optim/control.hpp>

#include <softdiff/core/threads.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace softdiff::app {

namespace {


bool parse_number(const std::string& s, double& v) {
  if (s.empty()) return false;
  char* end = nullptr;
  v = std::strtod(s.c_str(), &end);
  return *end == '\0' && std::isfinite(v);
}

// Goals over time: piecewise linear between the given times, constant outside.
struct Goals {
  std::vector<double> times;
  std::vector<Vec3> points;
  Vec3 at(double t) const {
    if (t <= times.front()) return points.front();
    if (t >= times.back()) return points.back();
    const auto it = std::upper_bound(times.begin(), times.end(), t);
    const std::size_t i = static_cast<std::size_t>(it - times.begin());
    const double s = (t - times[i - 1]) / (times[i] - times[i - 1]);
    return (1 - s) * points[i - 1] + s * points[i];
  }
};

// --target X,Y,Z or a CSV file `time,x,y,z`.
Goals parse_goals(const std::string& target) {
  Goals g;
  const auto items = split_list(target);
  double v[3];
  if (items.size() == 3 && parse_number(items[0], v[0]) && parse_number(items[1], v[1]) && parse_number(items[2], v[2])) {
    g.times = {0};
    g.points = {Vec3(v[0], v[1], v[2])};
    return g;
  }
  std::error_code ec;
  if (!std::filesystem::is_regular_file(target, ec))
    throw InputError("--target " + target + ": expected X,Y,Z (three numbers, metres) or a CSV file of timed goals "
                     "(time,x,y,z), and no such file exists");
  std::ifstream in(target);
  std::string line;
  int number = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++number;
    const auto f = split_list(line);
    const std::string where = target + ":" + std::to_string(number) + ": ";
    if (f.empty() || (f.size() == 1 && f[0].empty()) || f[0].rfind('#', 0) == 0) continue;
    if (!header) {
      std::string lower = line;
      std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return std::tolower(c); });
      if (split_list(lower) != std::vector<std::string>{"time", "x", "y", "z"})
        throw InputError(where + "expected the header line 'time,x,y,z', got '" + line + "'");
      header = true;
      continue;
    }
    if (f.size() != 4) throw InputError(where + "expected 4 comma-separated fields (time, x, y, z), got " + std::to_string(f.size()));
    double t = 0;
    if (!parse_number(f[0], t) || t < 0) throw InputError(where + "time: expected a number >= 0, got '" + f[0] + "'");
    if (!g.times.empty() && !(t > g.times.back()))
      throw InputError(where + "times must increase (" + f[0] + " after " + io::format_number(g.times.back()) + ")");
    Vec3 p;
    for (int c = 0; c < 3; ++c)
      if (!parse_number(f[1 + static_cast<std::size_t>(c)], p[c]))
        throw InputError(where + std::string(1, "xyz"[c]) + ": expected a finite number, got '" + f[1 + static_cast<std::size_t>(c)] + "'");
    g.times.push_back(t);
    g.points.push_back(p);
  }
  if (!header) throw InputError(target + ": empty (expected the header line 'time,x,y,z' and goals)");
  if (g.times.empty()) throw InputError(target + ": no goal after the header");
  return g;
}

}  // namespace

void add_control(CLI::App& app, ControlOptions& o) {
  app.add_option("scene", o.scene, "Scene file (YAML, docs/scene.md)")->required()->check(CLI::ExistingFile);
  app.add_option("--target", o.target, "Goal: X,Y,Z (metres) or a CSV file of timed goals (time,x,y,z)")->required();
  app.add_option("--effector", o.effector, "The controlled effector (default: the scene's first)");
  app.add_option("--steps", o.steps, "Number of steps (default: the scene's)")->check(positive_integer());
  app.add_option("--weights", o.weights,
                 "alpha,beta: weights of the goal term alpha |X_e - X_goal|^2 and of the contact-force term "
                 "beta |lambda_c,nodes|^2 (paper eq. 13)")
      ->capture_default_str();
  app.add_option("--axes", o.axes, "Controlled directions of the goal (a subset of xyz)")->capture_default_str();
  app.add_option("--regularization", o.regularization,
                 "Weight of |d lambda|^2, relative to the mean squared column of the objective's Jacobian")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--filter", o.filter, "Low-pass factor on the actuation change, in (0, 1] (1: none)")->capture_default_str();
  app.add_flag("--shared-actuation", o.shared,
               "One change for all actuators (a symmetric robot controlled for one side, as the paper's gripper)");
  app.add_flag("--max-actuation", o.max_actuation,
               "No QP: every actuator at its upper limit at every step (the paper's gripper heuristic, for comparison; "
               "the /control datasets are written the same way)");
  add_run_options(app, o.output, "Output HDF5 file (default: <scene stem>_control.h5)", o.force, o.set, o.threads,
                  o.strict, o.quiet, "No progress bar, no summary", o.json);
}

int run_control(const ControlOptions& o, const std::string& command_line) {
  set_threads(o.threads);  // the thread plan, core/threads.hpp
  const auto t_setup = Clock::now();
  std::vector<std::string> overrides = o.set;
  if (o.steps) overrides.push_back("simulation.steps=" + std::to_string(*o.steps));
  const io::SceneDesc scene = io::load_scene(o.scene, overrides);
  io::BuildReport report;
  report.strict = o.strict;
  const Model model = io::build_model(scene, &report);
  for (const auto& w : report.warnings) warn(w);
  // Rigid bodies (issue 21): their state is the step's input, not controlled; the step's
  // derivative goes through rigid contact. parse_theta below refuses what it does not
  // cover (rigidified parts: static, and a limited joint in contact on the sparse backend
  // or under Newton).
  if (model.step.integrator == IntegratorKind::static_equilibrium)
    throw InputError("control: the scene's integrator must be implicit_euler or bdf2 (inverse dynamics is per time step)");
  if (model.actuation.actuators.empty()) throw InputError("control: the scene has no actuators to control");
  parse_theta("control", "actuation", model);  // the step is differentiated with respect to the actuation
  const auto& effectors = model.actuation.effectors;
  if (effectors.empty()) throw InputError("control: the scene has no effectors (bodies[].effectors) to drive to the goal");
  optim::ControlOptions co;
  std::vector<std::string> names;
  for (const auto& e : effectors) names.push_back(model.fem.bodies[static_cast<std::size_t>(e.body)].name + "." + e.name);
  if (o.effector.empty()) {
    co.effector = 0;
  } else {
    co.effector = -1;
    for (std::size_t i = 0; i < effectors.size(); ++i)
      if (effectors[i].name == o.effector || names[i] == o.effector) {
        if (co.effector >= 0) throw InputError("--effector " + o.effector + ": ambiguous (give BODY.NAME: " + io::join(names) + ")");
        co.effector = static_cast<int>(i);
      }
    if (co.effector < 0) {
      std::string msg = "--effector " + o.effector + ": no such effector (the scene has " + io::join(names) + ")";
      if (const auto m = io::closest_match(o.effector, names)) msg += "; did you mean '" + *m + "'?";
      throw InputError(msg);
    }
  }
  const auto w = split_list(o.weights);
  double alpha = 0, beta = 0;
  if (w.size() != 2 || !parse_number(w[0], alpha) || !parse_number(w[1], beta) || alpha < 0 || beta < 0 || alpha + beta <= 0)
    throw InputError("--weights " + o.weights + ": expected alpha,beta (two numbers >= 0, not both 0)");
  if (beta > 0 && !model.contact.enabled)
    throw InputError("--weights " + o.weights + ": the contact-force weight beta needs contact, and this scene has none");
  co.alpha = alpha;
  co.beta = beta;
  co.axes = {false, false, false};
  if (o.axes.empty()) throw InputError("--axes: expected a subset of xyz, got nothing");
  for (const char c : o.axes) {
    if (c < 'x' || c > 'z') throw InputError("--axes " + o.axes + ": expected a subset of xyz");
    co.axes[static_cast<std::size_t>(c - 'x')] = true;
  }
  if (!(o.filter > 0 && o.filter <= 1)) throw InputError("--filter " + io::format_number(o.filter) + ": must be in (0, 1]");
  co.filter = o.filter;
  co.regularization = o.regularization;
  co.shared = o.shared;
  const Goals goals = parse_goals(o.target);

  std::filesystem::path out_path = o.output;
  if (out_path.empty()) out_path = std::filesystem::path(o.scene).stem().string() + "_control.h5";
  {
    std::vector<std::string> inputs = scene_input_files(scene);
    inputs.push_back(o.target);  // a CSV of goals (three numbers name no file)
    check_output_is_not_input(out_path.string(), inputs);
  }

  optim::InverseDynamics controller(model, co);
  const Eigen::Index na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  VecX previous;
  model.actuation.values(0.0, previous);
  for (Eigen::Index j = 0; j < na; ++j) {
    const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
    if (a.has_limits) previous[j] = std::clamp(previous[j], a.limits[0], a.limits[1]);
  }
  const auto& eff = effectors[static_cast<std::size_t>(co.effector)].effector;
  struct Series {
    int goal = -1, distance = -1, actuation = -1, force = -1, kkt = -1;
  } series;
  double kkt_max = 0, control_seconds = 0, distance = 0, min_distance = std::numeric_limits<double>::infinity();
  double last_kkt = 0;
  long steps_done = 0, qp_failures = 0;
  bool limits_ok = true;
  RunHooks hooks;
  hooks.data = &controller.data();  // one factorization per control step (optim/control.hpp)
  hooks.setup = [&](io::Hdf5Writer& wr) {
    std::vector<std::string> actuation_units;
    for (const auto& a : model.actuation.actuators) actuation_units.push_back(actuator_value_unit(a));
    series.goal = wr.add_series("/control/goal", 3, "m");
    series.distance = wr.add_series("/control/distance", 0, "m");
    series.actuation = wr.add_series("/control/actuation", static_cast<int>(na), column_units(actuation_units));
    if (model.contact.enabled) series.force = wr.add_series("/control/contact_force_norm", 0, "N");
    series.kkt = wr.add_series("/control/kkt_residual", 0, "1");  // relative to max(1, |g|_inf): box_qp.hpp
  };
  if (o.max_actuation)
    for (const auto& a : model.actuation.actuators)
      if (!a.has_limits) throw InputError("--max-actuation: actuator '" + a.name + "' has no limits");
  State history_state, history_next;
  long history_step = 0;
  hooks.actuation = [&](long k, const State& s, VecX& lambda) {
    if (o.max_actuation) {
      lambda.resize(na);
      for (Eigen::Index j = 0; j < na; ++j) lambda[j] = model.actuation.actuators[static_cast<std::size_t>(j)].limits[1];
      previous = lambda;
      steps_done = k;
      return StepStatus{};
    }
    const auto t0 = Clock::now();
    optim::ControlStep info;
    // BDF2's history: the state the hook saw at step k - 1 (steps run in order).
    const State* history = k > 1 && history_step == k - 1 ? &history_state : nullptr;
    const StepStatus st =
        controller.compute(model, s, k, goals.at(static_cast<double>(k) * model.step.dt), previous, lambda, info, history);
    if (st.ok()) {
      history_next = s;
      std::swap(history_state, history_next);
      history_step = k;
    }
    control_seconds += seconds_since(t0);
    if (!st.ok()) return st;
    kkt_max = std::max(kkt_max, info.kkt);
    last_kkt = info.kkt;
    qp_failures += !info.qp_converged;
    for (Eigen::Index j = 0; j < na; ++j) {
      const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
      if (a.has_limits && (lambda[j] < a.limits[0] || lambda[j] > a.limits[1])) limits_ok = false;
    }
    previous = lambda;
    steps_done = k;
    return StepStatus{};
  };
  hooks.frame = [&](io::Hdf5Writer& wr, const State& s, const Data& data, bool first) {
    const Vec3 goal = goals.at(s.t);
    Vec3 e = eff.position(s.x) - goal;
    for (int c = 0; c < 3; ++c)
      if (!co.axes[static_cast<std::size_t>(c)]) e[c] = 0;
    distance = e.norm();  // over the controlled axes
    if (!first) min_distance = std::min(min_distance, distance);
    wr.append_series(series.goal, goal.data());
    wr.append_series(series.distance, &distance);
    wr.append_series(series.actuation, previous.data());
    if (series.force >= 0) {
      const double f = first ? 0.0 : controller.contact_force_norm(model, data);
      wr.append_series(series.force, &f);
    }
    const double kkt = first ? 0.0 : last_kkt;
    wr.append_series(series.kkt, &kkt);
  };
  SimulateOptions so;
  so.scene = o.scene;
  so.output = out_path.string();
  so.force = o.force;
  so.strict = o.strict;
  so.quiet = o.quiet;   // the progress bar over the steps
  so.summary = false;   // control's own summary below
  const auto t_run = Clock::now();
  const int code = simulate_model(so, scene, model, t_setup, command_line, hooks);
  const double run_seconds = seconds_since(t_run);
  if (code != kExitOk) return code;
  const long n = std::max<long>(1, steps_done);
  if (!o.quiet) {
    std::ostringstream s;
    s.precision(4);
    s << steps_done << " control steps in " << run_seconds << " s (" << 1e3 * control_seconds / n
      << " ms/step in the controller, " << 1e3 * (run_seconds - control_seconds) / n << " ms/step in the rest); "
      << "final distance to the goal " << 1e3 * distance << " mm (closest " << 1e3 * min_distance
      << " mm), largest QP KKT residual " << kkt_max << " -> " << out_path.string();
    note(s.str());
  }
  if (qp_failures > 0) warn(std::to_string(qp_failures) + " steps' QP did not converge (see /control/kkt_residual)");
  if (o.json) {
    Json j;
    j.begin_object();
    j.value("command", "control").value("scene", o.scene).value("output", out_path.string());
    j.value("steps", steps_done).value("effector", names[static_cast<std::size_t>(co.effector)]);
    j.value("final_distance", distance).value("min_distance", min_distance);
    j.value("kkt_max", kkt_max).value("qp_not_converged_steps", qp_failures).value("within_limits", limits_ok);
    j.value("actuation_final", std::vector<double>(previous.data(), previous.data() + previous.size()));
    j.value("wall_seconds", run_seconds);
    j.value("control_ms_per_step", 1e3 * control_seconds / n);
    j.value("other_ms_per_step", 1e3 * (run_seconds - control_seconds) / n);
    j.end_object();
    std::printf("%s\n", j.str().c_str());
  }
  return kExitOk;
}

}  // namespace softdiff::app
