// Material identification: see calibration.hpp.
#include <softdiff/optim/calibration.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/parameters.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>
#include <softdiff/rigid/rotation.hpp>

#include <unsupported/Eigen/LevenbergMarquardt>

#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace softdiff::optim {

Eigen::Index CalibrationTarget::residual_size() const {
  if (!observations.empty()) return 3 * static_cast<Eigen::Index>(observations.size());
  Eigen::Index m = 0;
  for (const auto& s : states) m += s.size();
  return m + 6 * static_cast<Eigen::Index>(rigid.size() * frames.size());
}

double rigid_orientation_length(const rigid::RigidBody& body) { return std::sqrt(body.inertia.trace() / (3 * body.mass)); }

double to_internal(Parameter kind, double value) {
  if (kind == Parameter::poisson) {
    const double u = 2 * value;  // in (0, 1)
    return std::log(u / (1 - u));
  }
  return std::log(value);
}

double from_internal(Parameter kind, double z) {
  if (kind == Parameter::poisson) return 0.5 / (1 + std::exp(-z));
  return std::exp(z);
}

double dvalue_dinternal(Parameter kind, double z) {
  if (kind == Parameter::poisson) {
    const double s = 1 / (1 + std::exp(-z));
    return 0.5 * s * (1 - s);
  }
  return std::exp(z);
}

namespace {

// The rows of frame index f (into target.frames) from the state s (positions x, the
// rigid bodies' poses) and dx/dp (3n soft rows, then 6 per rigid body: position,
// rotation vector in world axes).
void fill_rows(const CalibrationTarget& target, int f, const State& s, const MatX* dx, VecX& r, MatX& J) {
  const VecX& x = s.x;
  if (target.observations.empty()) {
    const Eigen::Index per_frame = 6 * static_cast<Eigen::Index>(target.rigid.size());
    Eigen::Index row = per_frame * f;
    for (int g = 0; g < f && !target.states.empty(); ++g) row += target.states[static_cast<std::size_t>(g)].size();
    if (!target.states.empty()) {
      const VecX& y = target.states[static_cast<std::size_t>(f)];
      r.segment(row, y.size()) = x - y;
      if (dx) J.middleRows(row, y.size()) = dx->topRows(y.size());
      else J.middleRows(row, y.size()).setZero();
      row += y.size();
    }
    // Rigid poses: (p - p*, L delta), delta = log(q q*^-1). A change dtheta of the
    // orientation (q -> exp(dtheta) q, the sensitivities' rows) changes delta by
    // J_l(delta)^-1 dtheta (exp(e) exp(delta) = exp(delta + J_l^-1(delta) e), J_l(delta) =
    // J_r(delta)^T): exactly the identity at delta = 0.
    const Eigen::Index n3 = x.size();
    for (const auto& pose : target.rigid) {
      const auto fi = static_cast<std::size_t>(f);
      rigid::RigidState goal;
      goal.position = pose.position[fi];
      goal.orientation = pose.orientation[fi];
      const rigid::Vec12 d = rigid::tangent_between(goal, s.rigid[static_cast<std::size_t>(pose.body)]);
      r.segment<3>(row) = d.head<3>();
      r.segment<3>(row + 3) = pose.length * d.segment<3>(3);
      if (dx) {
        const Eigen::Index b = n3 + 6L * pose.body;
        J.middleRows<3>(row) = dx->middleRows<3>(b);
        const Mat3 Jl_inv = rigid::right_jacobian(Vec3(d.segment<3>(3))).transpose().inverse();
        J.middleRows<3>(row + 3).noalias() = (pose.length * Jl_inv) * dx->middleRows<3>(b + 3);
      } else {
        J.middleRows<6>(row).setZero();
      }
      row += 6;
    }
    return;
  }
  for (std::size_t i = 0; i < target.observations.size(); ++i) {
    const auto& o = target.observations[i];
    if (o.frame != f) continue;
    const Marker& m = target.markers[static_cast<std::size_t>(o.marker)];
    const Eigen::Index row = 3 * static_cast<Eigen::Index>(i);
    if (m.rigid_body >= 0) {
      // A point on a rigid body: p + R b. With q -> exp(dtheta) q, d(R b) = dtheta x (R b)
      // = -[R b] dtheta.
      const auto& rs = s.rigid[static_cast<std::size_t>(m.rigid_body)];
      const Vec3 arm = rs.orientation * m.body_point;
      r.segment<3>(row) = rs.position + arm - o.position;
      if (dx) {
        const Eigen::Index b = x.size() + 6L * m.rigid_body;
        J.middleRows<3>(row) = dx->middleRows<3>(b);
        J.middleRows<3>(row).noalias() -= rigid::hat(arm) * dx->middleRows<3>(b + 3);
      } else {
        J.middleRows<3>(row).setZero();
      }
      continue;
    }
    r.segment<3>(row) = m.point.position(x) - o.position;
    J.middleRows<3>(row).setZero();
    if (dx)
      for (int a = 0; a < m.point.count; ++a)
        J.middleRows<3>(row) += m.point.w[a] * dx->middleRows<3>(3 * m.point.nodes[a]);
  }
}

// "young[beam] = 1e6, friction[rule 0] = 0.5, mass[cube] = 0.1"
std::string describe_values(const Model& model, const std::vector<ParameterId>& parameters,
                            const std::vector<rigid::RigidParameterId>& rigid_parameters,
                            const std::vector<double>& values) {
  std::ostringstream s;
  s.precision(6);
  for (std::size_t j = 0; j < parameters.size(); ++j) {
    const ParameterId& id = parameters[j];
    s << (j ? ", " : "") << parameter_name(id.kind) << "[";
    if (id.kind == Parameter::friction) s << "rule " << id.body;
    else s << model.fem.bodies[static_cast<std::size_t>(id.body)].name;
    s << "] = " << values[j];
  }
  for (std::size_t j = 0; j < rigid_parameters.size(); ++j) {
    const auto& p = rigid_parameters[j];
    s << (parameters.empty() && j == 0 ? "" : ", ") << rigid::rigid_parameter_name(p.index) << "["
      << model.rigid[static_cast<std::size_t>(p.body)].name << "] = " << values[parameters.size() + j];
  }
  return s.str();
}

// Sets every parameter of m to values (soft ones, then rigid ones). A rigid inertia
// component that makes the inertia not positive definite (a diagonal one beside
// off-diagonal ones) is a failed run (ComputationError), as a run that fails.
void set_values(Model& m, const std::vector<ParameterId>& parameters,
                const std::vector<rigid::RigidParameterId>& rigid_parameters, const std::vector<double>& values) {
  for (std::size_t j = 0; j < parameters.size(); ++j) diff::set_parameter(m, parameters[j], values[j]);
  for (std::size_t j = 0; j < rigid_parameters.size(); ++j) {
    const auto& p = rigid_parameters[j];
    try {
      rigid::set_parameter(m.rigid[static_cast<std::size_t>(p.body)], p.index, values[parameters.size() + j]);
    } catch (const std::invalid_argument& e) {
      throw ComputationError(std::string("calibration: ") + e.what());
    }
  }
}

}  // namespace

namespace {

// One run of m (the parameters already set to `values`) on data (fresh, or restarted
// for m): the residual and its Jacobian.
void run(const Model& m, Data& data, const std::vector<ParameterId>& parameters,
         const std::vector<rigid::RigidParameterId>& rigid_parameters, const std::vector<double>& values,
         const CalibrationTarget& target, bool strict, VecX& r, MatX& J,
         const std::function<void(long step, long steps)>& on_step) {
  const Eigen::Index rows = target.residual_size();
  r.setZero(rows);
  J.setZero(rows, static_cast<Eigen::Index>(parameters.size() + rigid_parameters.size()));
  const auto failed = [&](const StepStatus& st) {
    throw ComputationError("calibration: the run with " + describe_values(m, parameters, rigid_parameters, values) +
                           " failed: " + describe(m, st));
  };
  if (m.step.integrator == IntegratorKind::static_equilibrium) {
    State eq;
    const long load_steps = m.step.static_load_steps;
    if (on_step) on_step(0, load_steps);
    const StepStatus st = integrator::solve_static(m, data, m.initial, eq, [&](long k, const State&) {
      if (on_step) on_step(k, load_steps);
    });
    if (!st.ok()) failed(st);
    MatX dx;
    integrator::StaticTheta theta{parameters, false, {}};
    for (const auto& id : rigid_parameters) theta.rigid_parameters.emplace_back(id.body, id.index);
    if (!integrator::static_sensitivities(m, data, eq, theta, dx))
      throw ComputationError("calibration: the derivative of the equilibrium failed with " +
                             describe_values(m, parameters, rigid_parameters, values));
    for (int f = 0; f < static_cast<int>(target.frames.size()); ++f) fill_rows(target, f, eq, &dx, r, J);
    return;
  }
  diff::ThetaLayout layout;
  layout.parameters = parameters;
  layout.rigid_parameters = rigid_parameters;
  diff::ForwardSensitivity sensitivity(m, layout);
  State s = m.initial, next = m.initial, previous;  // previous: BDF2's history
  std::size_t f = 0;
  if (target.frames[0] == 0) fill_rows(target, static_cast<int>(f++), s, nullptr, r, J);
  if (on_step) on_step(0, target.steps());
  for (long k = 1; k <= target.steps(); ++k) {
    const StepStatus st = integrator::time_step(m, data, s, k > 1 ? &previous : nullptr, next, k);
    if (!st.ok()) failed(st);
    if (strict && m.contact.enabled && !data.contact.result.converged) {
      StepStatus c;
      c.code = StepStatus::Code::contact_not_converged;
      c.step = k;
      c.detail = "the contact solve did not reach its tolerance (largest residual " +
                 std::to_string(data.contact.result.residuals.max()) + "; --strict)";
      failed(c);
    }
    if (!sensitivity.advance(m, data, s, next)) {
      StepStatus c;
      c.code = StepStatus::Code::solver_failed;
      c.step = k;
      c.detail = "the derivative of the step failed";
      failed(c);
    }
    std::swap(previous, s);
    std::swap(s, next);
    if (on_step) on_step(k, target.steps());
    if (f < target.frames.size() && target.frames[f] == k) {
      fill_rows(target, static_cast<int>(f), s, &sensitivity.dx_dtheta(), r, J);
      ++f;
    }
  }
  if (!r.allFinite() || !J.allFinite())
    throw ComputationError("calibration: non-finite residual or Jacobian with " + describe_values(m, parameters, rigid_parameters, values));
}

}  // namespace

void residual(const Model& model, const std::vector<ParameterId>& parameters, const std::vector<double>& values,
              const CalibrationTarget& target, bool strict, VecX& r, MatX& J,
              const std::function<void(long step, long steps)>& on_step) {
  residual(model, parameters, {}, values, target, strict, r, J, on_step);
}

void residual(const Model& model, const std::vector<ParameterId>& parameters,
              const std::vector<rigid::RigidParameterId>& rigid_parameters, const std::vector<double>& values,
              const CalibrationTarget& target, bool strict, VecX& r, MatX& J,
              const std::function<void(long step, long steps)>& on_step) {
  SOFTDIFF_DEMAND(parameters.size() + rigid_parameters.size() == values.size(), "calibration: one value per parameter");
  SOFTDIFF_DEMAND(!target.frames.empty(), "calibration: the target has no frame");
  Model m = model;
  set_values(m, parameters, rigid_parameters, values);
  Data data(m);
  run(m, data, parameters, rigid_parameters, values, target, strict, r, J, on_step);
}

CalibrationWorkspace::CalibrationWorkspace(const Model& model, std::vector<ParameterId> parameters,
                                           std::vector<rigid::RigidParameterId> rigid_parameters)
    : base_(model), parameters_(std::move(parameters)), rigid_parameters_(std::move(rigid_parameters)), model_(model),
      data_(model_) {
  for (const auto& p : parameters_) friction_ = friction_ || p.kind == Parameter::friction;
}

void CalibrationWorkspace::residual(const std::vector<double>& values, const CalibrationTarget& target, bool strict,
                                    VecX& r, MatX& J, const std::function<void(long step, long steps)>& on_step) {
  SOFTDIFF_DEMAND(parameters_.size() + rigid_parameters_.size() == values.size(), "calibration: one value per parameter");
  SOFTDIFF_DEMAND(!target.frames.empty(), "calibration: the target has no frame");
  // Every parameter back to the base model's value, then set in order: the same model
  // as set_parameter on a fresh copy (a density set on top of the last run's would
  // compound the rounding of the mass ratios).
  for (const auto& p : parameters_) diff::restore_parameter(model_, base_, p);
  for (const auto& p : rigid_parameters_) {  // a body's mass and inertia: nothing is derived from them
    const auto b = static_cast<std::size_t>(p.body);
    model_.rigid[b].mass = base_.rigid[b].mass;
    model_.rigid[b].inertia = base_.rigid[b].inertia;
  }
  set_values(model_, parameters_, rigid_parameters_, values);
  data_.restart(model_, friction_);
  ++runs_;
  run(model_, data_, parameters_, rigid_parameters_, values, target, strict, r, J, on_step);
}

namespace {

// |r| reported for a failed trial: ten times the current residual norm, i.e. a cost
// 100 times the current one (see Functor::operator()).
constexpr double kFailedCostFactor = 10;

// Eigen's Levenberg-Marquardt functor over the internal coordinates z. Each evaluation
// runs the simulation with its sensitivities on the one workspace; the Jacobian of the last two evaluated
// points is kept, so that df() at an accepted point costs nothing.
struct Functor : Eigen::DenseFunctor<double> {
  Functor(const Model& model, const std::vector<ParameterId>& parameters,
          const std::vector<rigid::RigidParameterId>& rigid_parameters, const CalibrationTarget& target, bool strict,
          const std::function<void(int, long, long)>& on_step)
      : Eigen::DenseFunctor<double>(static_cast<int>(parameters.size() + rigid_parameters.size()),
                                    static_cast<int>(target.residual_size())),
        parameters(parameters), target(target), strict(strict), on_step(on_step),
        workspace(model, parameters, rigid_parameters) {}

  // The value of unknown j from its internal coordinate z and the derivative: the soft
  // parameters' reparametrization, log for the rigid ones (mass, inertia diagonal).
  double value(std::size_t j, double z) const {
    return j < parameters.size() ? from_internal(parameters[j].kind, z) : std::exp(z);
  }
  double dvalue(std::size_t j, double z) const {
    return j < parameters.size() ? dvalue_dinternal(parameters[j].kind, z) : std::exp(z);
  }

  struct Evaluation {
    VecX z, r;
    MatX J;  // dr/dp (physical)
  };

  std::vector<double> physical(const VecX& z) const {
    std::vector<double> v(static_cast<std::size_t>(z.size()));
    for (std::size_t j = 0; j < v.size(); ++j) v[j] = value(j, z[static_cast<Eigen::Index>(j)]);
    return v;
  }
  const Evaluation& evaluate(const VecX& z) {
    for (const auto& e : cache)
      if (e.z.size() == z.size() && e.z == z) return e;
    Evaluation e;
    e.z = z;
    const int run = evaluations + 1;
    workspace.residual(physical(z), target, strict, e.r, e.J, [&](long k, long n) {
      if (on_step) on_step(run, k, n);
    });
    ++evaluations;
    cache[next] = std::move(e);
    const Evaluation& out = cache[next];
    next = 1 - next;
    return out;
  }
  // Inside minimizeOneStep every evaluation is a trial point z + dz. A trial whose run
  // fails (an inverted element, a Newton step that does not converge, ...) is a
  // rejected step: MINPACK's lmder has no way to be told that a trial failed, so it
  // gets a residual kFailedCostFactor times the current one in norm (|r(z)|, set by
  // calibrate before each iteration). Its actual reduction is then negative, the
  // ratio to the predicted reduction below 1e-4: the step is rejected, the trust
  // region shrinks tenfold (lmder's factor for fnorm1 >= 10 fnorm) and the damping
  // grows, exactly as for a step that raises the cost. The failed point never enters
  // the cache, so it can never be accepted.
  int operator()(const VecX& z, VecX& fvec) {
    if (!in_step) {
      fvec = evaluate(z).r;
      return 0;
    }
    // The step test before the trial's run (docs/method.md "Calibration", "Stopping"):
    // a trial step z - z_k with |D (z - z_k)| <= xtol |D z_k| (D: lmder's column scaling,
    // the norms of its xtol test) is not run; the iteration stops at z_k. Returning -1
    // makes minimizeOneStep return UserAsked without touching z.
    if (diag != nullptr && xtol > 0) {
      const double step = diag->cwiseProduct(z - current_z).stableNorm();
      if (step <= xtol * diag->cwiseProduct(current_z).stableNorm()) {
        stopped_on_step = true;
        return -1;
      }
    }
    try {
      fvec = evaluate(z).r;
    } catch (const ComputationError& e) {
      ++evaluations;
      ++failed;
      last_failure = e.what();
      const double norm = kFailedCostFactor * (current_norm > 0 ? current_norm : 1.0);
      fvec = VecX::Constant(values(), norm / std::sqrt(static_cast<double>(values())));
    }
    return 0;
  }
  int df(const VecX& z, MatX& fjac) {
    const Evaluation& e = evaluate(z);
    fjac = e.J;
    for (Eigen::Index j = 0; j < z.size(); ++j)
      fjac.col(j) *= dvalue(static_cast<std::size_t>(j), z[j]);
    return 0;
  }

  const std::vector<ParameterId>& parameters;
  const CalibrationTarget& target;
  bool strict;
  const std::function<void(int, long, long)>& on_step;
  CalibrationWorkspace workspace;  // every run's model and Data
  Evaluation cache[2];
  int next = 0;
  int evaluations = 0;
  bool in_step = false;      // evaluations are trial points of minimizeOneStep
  VecX current_z;            // the current (accepted) point, set by calibrate before each iteration
  const VecX* diag = nullptr;  // lmder's column scaling D (LevenbergMarquardt::diag())
  double xtol = 0;           // the relative step tolerance
  bool stopped_on_step = false;  // a trial step was below xtol and not run
  double current_norm = 0;   // |r| at the current (accepted) point
  int failed = 0;            // trial runs that failed (counted in evaluations)
  std::string last_failure;  // the message of the last failed trial run
};


const char* status_text(Eigen::LevenbergMarquardtSpace::Status s) {
  using namespace Eigen::LevenbergMarquardtSpace;
  switch (s) {
    case RelativeReductionTooSmall: return "relative reduction of the cost below ftol";
    case RelativeErrorTooSmall: return "relative step below xtol";
    case RelativeErrorAndReductionTooSmall: return "relative reduction below ftol and relative step below xtol";
    case CosinusTooSmall: return "gradient orthogonal to the residual (below gtol)";
    case TooManyFunctionEvaluation: return "too many function evaluations";
    case FtolTooSmall: return "no further reduction of the cost possible at machine precision";
    case XtolTooSmall: return "no further improvement of the parameters possible at machine precision";
    case GtolTooSmall: return "the residual is orthogonal to the Jacobian's columns at machine precision";
    case ImproperInputParameters: return "improper input (a zero-size problem or a failed QR)";
    case UserAsked: return "stopped by the residual";
    default: return "running";
  }
}

bool converged_status(Eigen::LevenbergMarquardtSpace::Status s) {
  using namespace Eigen::LevenbergMarquardtSpace;
  return s == RelativeReductionTooSmall || s == RelativeErrorTooSmall || s == RelativeErrorAndReductionTooSmall ||
         s == CosinusTooSmall || s == FtolTooSmall || s == XtolTooSmall || s == GtolTooSmall;
}

}  // namespace

CalibrationResult calibrate(const Model& model, const std::vector<ParameterId>& parameters,
                            const std::vector<double>& initial, const CalibrationTarget& target,
                            const CalibrationOptions& options, const IterationCallback& callback) {
  return calibrate(model, parameters, {}, initial, target, options, callback);
}

CalibrationResult calibrate(const Model& model, const std::vector<ParameterId>& parameters,
                            const std::vector<rigid::RigidParameterId>& rigid_parameters,
                            const std::vector<double>& initial, const CalibrationTarget& target,
                            const CalibrationOptions& options, const IterationCallback& callback) {
  SOFTDIFF_DEMAND(parameters.size() + rigid_parameters.size() == initial.size() && !initial.empty(),
                  "calibrate: one initial value per parameter");
  const auto t0 = std::chrono::steady_clock::now();
  Functor functor(model, parameters, rigid_parameters, target, options.strict, options.on_step);
  Eigen::LevenbergMarquardt<Functor> lm(functor);
  lm.setFtol(options.ftol);
  lm.setXtol(options.xtol);
  lm.setGtol(options.gtol);
  lm.setMaxfev(1000000);
  VecX z(static_cast<Eigen::Index>(initial.size()));
  for (std::size_t j = 0; j < initial.size(); ++j)
    z[static_cast<Eigen::Index>(j)] = j < parameters.size() ? to_internal(parameters[j].kind, initial[j]) : std::log(initial[j]);

  CalibrationResult result;
  int evaluations_before = 0, failed_before = 0;
  bool moved = true;
  const auto record = [&](int iteration) {
    const Functor::Evaluation& e = functor.evaluate(z);  // cached: the accepted point
    CalibrationIteration it;
    it.iteration = iteration;
    it.values = functor.physical(z);
    it.cost = 0.5 * e.r.squaredNorm();
    it.gradient_norm = (e.J.transpose() * e.r).norm();
    it.damping = iteration == 0 ? 0.0 : lm.lm_param();
    it.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    it.evaluations = functor.evaluations;
    if (iteration > 0) {
      const int trials = functor.evaluations - evaluations_before;
      it.failed = functor.failed - failed_before;
      it.rejected = trials - (moved ? 1 : 0);
      if (it.failed > 0) it.last_failure = functor.last_failure;
    }
    result.history.push_back(it);
    if (callback) callback(it);
  };
  Eigen::LevenbergMarquardtSpace::Status status = lm.minimizeInit(z);
  if (status == Eigen::LevenbergMarquardtSpace::ImproperInputParameters) {
    result.stop_reason = status_text(status);
    return result;
  }
  record(0);
  result.stop_reason = "the maximum number of iterations was reached";
  for (int it = 1; it <= options.max_iterations; ++it) {
    evaluations_before = functor.evaluations;
    failed_before = functor.failed;
    const VecX z_before = z;
    functor.current_norm = lm.fnorm();
    functor.current_z = z;
    functor.diag = &lm.diag();
    functor.xtol = options.xtol;
    functor.in_step = true;
    status = lm.minimizeOneStep(z);
    functor.in_step = false;
    moved = z != z_before;
    record(it);
    result.iterations = it;
    result.rejected += result.history.back().rejected;
    result.failed += result.history.back().failed;
    if (status != Eigen::LevenbergMarquardtSpace::Running) {
      result.converged = converged_status(status);
      result.stop_reason = status_text(status);
      if (status == Eigen::LevenbergMarquardtSpace::UserAsked && functor.stopped_on_step) {
        result.converged = true;
        result.stop_reason = "relative step below xtol (the trial was not run)";
      }
      // The trust region shrank below xtol through failed trial runs alone: not a
      // convergence.
      if (!moved && result.history.back().failed > 0) {
        result.converged = false;
        result.stop_reason = "the runs of the trial steps failed down to the smallest step (last: " +
                             functor.last_failure + ")";
      }
      break;
    }
  }
  result.values = functor.physical(z);
  result.cost = result.history.back().cost;
  result.evaluations = functor.evaluations;
  return result;
}

}  // namespace softdiff::optim
