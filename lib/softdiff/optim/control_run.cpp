// `softdiff control` as a library call: control_run.hpp. Moved from app/cmd_control.cpp
// (2026-12-04, branch pycal), the messages unchanged.
#include <softdiff/optim/control_run.hpp>

#include <softdiff/core/error.hpp>
#include <softdiff/core/text.hpp>
#include <softdiff/core/timer.hpp>
#include <softdiff/diff/theta_selection.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/contact_status.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/units.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <utility>

namespace softdiff::optim {

namespace {

bool parse_number(const std::string& s, double& v) {
  if (s.empty()) return false;
  char* end = nullptr;
  v = std::strtod(s.c_str(), &end);
  return *end == '\0' && std::isfinite(v);
}

}  // namespace

Vec3 Goals::at(double t) const {
  if (t <= times.front()) return points.front();
  if (t >= times.back()) return points.back();
  const auto it = std::upper_bound(times.begin(), times.end(), t);
  const std::size_t i = static_cast<std::size_t>(it - times.begin());
  const double s = (t - times[i - 1]) / (times[i] - times[i - 1]);
  return (1 - s) * points[i - 1] + s * points[i];
}

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

ControlProblem prepare_control(const ControlRunOptions& o, const ControlMessageSink& warn) {
  std::vector<std::string> overrides = o.set;
  if (o.steps) overrides.push_back("simulation.steps=" + std::to_string(*o.steps));
  ControlProblem p;
  p.scene = io::load_scene(o.scene, overrides);
  io::BuildReport report;
  report.strict = o.strict;
  p.model = io::build_model(p.scene, &report);
  const Model& model = p.model;
  if (warn)
    for (const auto& w : report.warnings) warn(w);
  // Rigid bodies (issue 21): their state is the step's input, not controlled; the step's
  // derivative goes through rigid contact. parse_theta below refuses what it does not
  // cover (rigidified parts: static, and a limited joint in contact on the sparse backend
  // or under Newton).
  if (model.step.integrator == IntegratorKind::static_equilibrium)
    throw InputError("control: the scene's integrator must be implicit_euler or bdf2 (inverse dynamics is per time step)");
  if (model.actuation.actuators.empty()) throw InputError("control: the scene has no actuators to control");
  diff::parse_theta("control", "actuation", model);  // the step is differentiated with respect to the actuation
  const auto& effectors = model.actuation.effectors;
  if (effectors.empty()) throw InputError("control: the scene has no effectors (bodies[].effectors) to drive to the goal");
  ControlOptions& co = p.options;
  std::vector<std::string>& names = p.effector_names;
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
  p.goals = parse_goals(o.target);
  return p;
}

ControlRun::ControlRun(const ControlProblem& problem, bool max_actuation)
    : problem_(problem), max_actuation_(max_actuation), controller_(problem.model, problem.options) {
  const Model& model = problem_.model;
  const Eigen::Index na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  model.actuation.values(0.0, previous_);
  for (Eigen::Index j = 0; j < na; ++j) {
    const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
    if (a.has_limits) previous_[j] = std::clamp(previous_[j], a.limits[0], a.limits[1]);
  }
  min_distance_ = std::numeric_limits<double>::infinity();
  if (max_actuation_)
    for (const auto& a : model.actuation.actuators)
      if (!a.has_limits) throw InputError("--max-actuation: actuator '" + a.name + "' has no limits");
}

StepStatus ControlRun::actuation(long k, const State& s, VecX& lambda) {
  const Model& model = problem_.model;
  const Eigen::Index na = static_cast<Eigen::Index>(model.actuation.actuators.size());
  if (max_actuation_) {
    lambda.resize(na);
    for (Eigen::Index j = 0; j < na; ++j) lambda[j] = model.actuation.actuators[static_cast<std::size_t>(j)].limits[1];
    previous_ = lambda;
    steps_done_ = k;
    return StepStatus{};
  }
  const auto t0 = Clock::now();
  ControlStep info;
  // BDF2's history: the state the hook saw at step k - 1 (steps run in order).
  const State* history = k > 1 && history_step_ == k - 1 ? &history_state_ : nullptr;
  const StepStatus st = controller_.compute(model, s, k, problem_.goals.at(static_cast<double>(k) * model.step.dt),
                                            previous_, lambda, info, history);
  if (st.ok()) {
    history_next_ = s;
    std::swap(history_state_, history_next_);
    history_step_ = k;
  }
  control_seconds_ += seconds_since(t0);
  if (!st.ok()) return st;
  kkt_max_ = std::max(kkt_max_, info.kkt);
  last_kkt_ = info.kkt;
  qp_failures_ += !info.qp_converged;
  for (Eigen::Index j = 0; j < na; ++j) {
    const auto& a = model.actuation.actuators[static_cast<std::size_t>(j)];
    if (a.has_limits && (lambda[j] < a.limits[0] || lambda[j] > a.limits[1])) limits_ok_ = false;
  }
  previous_ = lambda;
  steps_done_ = k;
  return StepStatus{};
}

void ControlRun::observe(const State& s, const Data& data, bool first) {
  const Model& model = problem_.model;
  const auto& eff = model.actuation.effectors[static_cast<std::size_t>(problem_.options.effector)].effector;
  frame_.goal = problem_.goals.at(s.t);
  Vec3 e = eff.position(s.x) - frame_.goal;
  for (int c = 0; c < 3; ++c)
    if (!problem_.options.axes[static_cast<std::size_t>(c)]) e[c] = 0;
  distance_ = e.norm();  // over the controlled axes
  if (!first) min_distance_ = std::min(min_distance_, distance_);
  frame_.distance = distance_;
  frame_.force_norm = model.contact.enabled && !first ? controller_.contact_force_norm(model, data) : 0.0;
  frame_.kkt = first ? 0.0 : last_kkt_;
}

ControlSummary ControlRun::summary() const {
  ControlSummary s;
  s.steps = steps_done_;
  s.effector = problem_.effector_names[static_cast<std::size_t>(problem_.options.effector)];
  s.final_distance = distance_;
  s.min_distance = min_distance_;
  s.kkt_max = kkt_max_;
  s.qp_not_converged_steps = qp_failures_;
  s.within_limits = limits_ok_;
  s.actuation_final.assign(previous_.data(), previous_.data() + previous_.size());
  s.control_seconds = control_seconds_;
  return s;
}

ControlRunResult run_control(const ControlProblem& problem, bool max_actuation, bool strict, const ControlMessageSink& warn) {
  const Model& model = problem.model;
  ControlRun run(problem, max_actuation);
  Data& data = run.data();
  ControlRunResult out;
  const long total = model.step.steps;
  const long every = std::max<long>(1, problem.scene.output.every);
  const auto record = [&](const State& st, bool first) {
    run.observe(st, data, first);
    out.times.push_back(st.t);
    out.frames.push_back(run.frame());
    out.actuation.push_back(run.applied());
  };
  const auto t_run = Clock::now();
  State state = model.initial, next = model.initial, previous;
  VecX applied = VecX::Zero(static_cast<Eigen::Index>(model.actuation.actuators.size()));
  record(state, true);
  for (long k = 1; k <= total; ++k) {
    StepStatus s = run.actuation(k, state, applied);
    if (s.ok()) s = integrator::time_step(model, data, state, k > 1 ? &previous : nullptr, next, k, &applied);
    const StepStatus failure = integrator::strict_or_warn(model, data, k, s, strict, out.newton_not_converged_steps,
                                                          out.contact_not_converged_steps, warn);
    if (!failure.ok()) throw ComputationError(describe(model, failure));
    std::swap(previous, state);  // BDF2's history
    std::swap(state, next);
    if (k % every == 0 || k == total) record(state, false);
  }
  out.run_seconds = seconds_since(t_run);
  out.summary = run.summary();
  return out;
}

std::string control_output_path(const ControlRunOptions& o, const std::string& output, const io::SceneDesc& scene) {
  std::filesystem::path out_path = output;
  if (out_path.empty()) out_path = std::filesystem::path(o.scene).stem().string() + "_control.h5";
  std::vector<std::string> inputs = io::scene_input_files(scene);
  inputs.push_back(o.target);  // a CSV of goals (three numbers name no file)
  io::check_output_is_not_input(out_path.string(), inputs);
  return out_path.string();
}

io::RunHooks control_output_hooks(const ControlProblem& problem, ControlRun& run,
                                  std::function<void(const State& s)> on_frame) {
  const Model& model = problem.model;
  struct Series {
    int goal = -1, distance = -1, actuation = -1, force = -1, kkt = -1;
  };
  auto series = std::make_shared<Series>();  // shared by the hooks (copies of one another)
  io::RunHooks hooks;
  hooks.data = &run.data();  // one factorization per control step (optim/control.hpp)
  hooks.setup = [&model, series](io::Hdf5Writer& wr) {
    const Eigen::Index na = static_cast<Eigen::Index>(model.actuation.actuators.size());
    std::vector<std::string> actuation_units;
    for (const auto& a : model.actuation.actuators) actuation_units.push_back(io::actuator_value_unit(a));
    series->goal = wr.add_series("/control/goal", 3, "m");
    series->distance = wr.add_series("/control/distance", 0, "m");
    series->actuation = wr.add_series("/control/actuation", static_cast<int>(na), io::column_units(actuation_units));
    if (model.contact.enabled) series->force = wr.add_series("/control/contact_force_norm", 0, "N");
    series->kkt = wr.add_series("/control/kkt_residual", 0, "1");  // relative to max(1, |g|_inf): box_qp.hpp
  };
  hooks.actuation = [&run](long k, const State& s, VecX& lambda) { return run.actuation(k, s, lambda); };
  hooks.frame = [&run, series, on_frame = std::move(on_frame)](io::Hdf5Writer& wr, const State& s, const Data& data,
                                                                 bool first) {
    run.observe(s, data, first);
    const auto& f = run.frame();
    wr.append_series(series->goal, f.goal.data());
    wr.append_series(series->distance, &f.distance);
    wr.append_series(series->actuation, run.applied().data());
    if (series->force >= 0) wr.append_series(series->force, &f.force_norm);
    wr.append_series(series->kkt, &f.kkt);
    if (on_frame) on_frame(s);
  };
  return hooks;
}

}  // namespace softdiff::optim
