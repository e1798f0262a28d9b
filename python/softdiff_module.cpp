// softdiff._softdiff: the Python module's extension (pybind11; API in docs/python.md,
// contract /work/shared/spec/python.md). The package softdiff (python/softdiff/
// __init__.py) re-exports it and adds the Python-side conveniences (overrides given
// as a dict).
//
// Everything here calls the library exactly as `softdiff simulate` does (app/
// cmd_simulate.cpp): io::load_scene with the --set strings, io::build_model, one
// Data workspace, integrator::time_step per step with the previous state for BDF2,
// the same Newton / contact non-convergence policy (a warning, or with strict=True a
// failure) and the same messages (describe(model, status)). Input errors
// (softdiff::InputError, the CLI's exit code 2) become softdiff.SceneError, failed
// computations (a StepStatus that is not ok, softdiff::ComputationError, exit 1)
// softdiff.StepError; both carry `exit_code` (2, 1) for scripts that mirror the CLI.
//
// The GIL is released during every step (the step never touches Python objects: the
// frames of run() are copied into numpy buffers allocated before the loop).
#include <softdiff/core/error.hpp>
#include <softdiff/core/threads.hpp>
#include <softdiff/data.hpp>
#include <softdiff/diff/parameters.hpp>  // torch support (ptorch): set_parameter, restore_parameter
#include <softdiff/diff/theta_selection.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/bdf2_derivatives.hpp>  // pyrig
#include <softdiff/integrator/contact_status.hpp>
#include <softdiff/integrator/implicit_euler_derivatives.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/hdf5_reader.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>
#include <softdiff/optim/calibrate_run.hpp>  // calibrate/control (pycal)
#include <softdiff/optim/control_run.hpp>    // calibrate/control (pycal)
#include <softdiff/io/input_error.hpp>       // calibrate/control (pycal): io::join
#include <softdiff/io/run_output.hpp>        // output files (pyout): io::OutputRun
#include <softdiff/io/hdf5_writer.hpp>       // output files (pyout)
#include <softdiff/version.hpp>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <memory>
#include <new>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace py = pybind11;

namespace softdiff::python {
namespace {

// The exception types, created at import (module_::def below) and kept alive by the module.
PyObject* g_scene_error = nullptr;
PyObject* g_step_error = nullptr;
PyObject* g_convergence_warning = nullptr;
PyObject* g_scene_warning = nullptr;

// Raises `type(message)` with the given attributes set on the instance.
[[noreturn]] void raise(PyObject* type, const std::string& message, const py::dict& attributes = py::dict()) {
  py::object exc = py::reinterpret_borrow<py::object>(type)(message);
  for (auto item : attributes) py::setattr(exc, item.first, item.second);
  PyErr_SetObject(type, exc.ptr());
  throw py::error_already_set();
}

// A scene, loaded and validated (load_scene); the model is built by Simulator.
struct Scene {
  io::SceneDesc desc;
  std::string path;
  std::vector<std::string> overrides;
};

Scene load_scene(const std::string& path, const std::vector<std::string>& overrides) {
  Scene s;
  s.path = path;
  s.overrides = overrides;
  try {
    py::gil_scoped_release release;  // the mesh is not read here, but files are
    s.desc = io::load_scene(path, overrides);
  } catch (const InputError& e) {
    raise(g_scene_error, e.what());
  }
  return s;
}

// The simulator: a model, its workspace and the state. x(), v(): copies (the step
// swaps the state's buffers, so a view would silently change meaning at the next
// step; docs/python.md "Copies and views").
class Simulator {
 public:
  Simulator(const Scene& scene, int threads, bool strict, const std::optional<std::string>& jacobian)
      : threads_(threads), strict_(strict) {
    if (threads < 0) throw py::value_error("threads must be >= 0 (0: all cores), got " + std::to_string(threads));
    io::BuildReport report;
    report.strict = strict;
    try {
      py::gil_scoped_release release;
      plan_threads_ = set_threads(threads_).threads;  // threads 0: what OpenMP's default resolved to
      model_ = std::make_unique<Model>(io::build_model(scene.desc, &report));
    } catch (const InputError& e) {
      raise(g_scene_error, e.what());
    } catch (const ComputationError& e) {
      raise(g_step_error, e.what());
    }
    for (const auto& w : report.warnings) warn(w, g_scene_warning);
    is_static_ = model_->step.integrator == IntegratorKind::static_equilibrium;
    if (jacobian) {
      // The theta groups of `simulate --jacobian` (diff/theta_selection.hpp), its checks
      // and messages (with "jacobian" for the option's name).
      try {
        theta_ = diff::parse_theta("jacobian", *jacobian, *model_);
      } catch (const InputError& e) {
        raise(g_scene_error, e.what());
      }
      if (!is_static_) sensitivity_ = std::make_unique<diff::ForwardSensitivity>(*model_, theta_->layout);
    }
    data_ = std::make_unique<Data>(*model_);
    state_ = model_->initial;
    next_ = model_->initial;
    for (std::size_t b = 0; b < model_->fem.bodies.size(); ++b) names_.push_back(model_->fem.bodies[b].name);
    for (std::size_t r = 0; r < model_->rigid.size(); ++r) names_.push_back(model_->rigid[r].name);
  }

  double time() const { return state_.t; }
  long steps_done() const { return k_; }
  double dt() const { return model_->step.dt; }
  long scene_steps() const { return model_->step.steps; }
  int threads() const { return threads_; }
  const std::vector<std::string>& bodies() const { return names_; }
  long newton_not_converged() const { return newton_not_converged_; }
  long contact_not_converged() const { return contact_not_converged_; }

  // d x / d theta (or d v / d theta) at the current state, per theta group: (rows, k)
  // copies of the forward sensitivities' columns (Fortran order: a column block of the
  // column-major matrix, one memcpy).
  py::dict jacobian(const std::string& of) const {
    if (!theta_) throw py::value_error("no theta: give Simulator(scene, jacobian=\"young, ...\") first");
    if (of != "x" && of != "v") throw py::value_error("of: 'x' or 'v', got '" + of + "'");
    if (is_static_ && of == "v") throw py::value_error("of='v': a static equilibrium has no velocities");
    if (is_static_ && !solved_) throw py::value_error("jacobian(): run() solves the static equilibrium first");
    const MatX& J = is_static_ ? static_jacobian_ : of == "x" ? sensitivity_->dx_dtheta() : sensitivity_->dv_dtheta();
    py::dict out;
    for (const auto& g : theta_->groups) {
      py::array_t<double, py::array::f_style> a({static_cast<py::ssize_t>(J.rows()), static_cast<py::ssize_t>(g.size)});
      std::memcpy(a.mutable_data(), J.col(g.offset).data(), sizeof(double) * static_cast<std::size_t>(J.rows() * g.size));
      out[py::str(g.name)] = a;
    }
    return out;
  }
  py::dict theta_columns() const {
    py::dict out;
    if (theta_)
      for (const auto& g : theta_->groups) out[py::str(g.name)] = g.columns;
    return out;
  }
  // --- pyrig --- the last step's JVP and VJP with rigid bodies and BDF2 (issue 23 item 2)
  // The state's tangent is laid out as jacobian()'s rows: dx = the soft bodies' 3 n
  // coordinates, then 6 per rigid body (position, rotation vector of the orientation
  // change in world axes, q + dq = exp(dtheta) q); dv = 3 n, then 6 per rigid body
  // (velocity, angular velocity). BDF2's step reads two frames: dx_prev, dv_prev are the
  // tangent of the frame before the step's input (x_{n-1}; zero contribution on an
  // implicit Euler step: implicit_euler scenes, BDF2's first step, a restart), and the
  // VJP returns that frame's cotangent as "x_prev", "v_prev". The products are those of
  // the library's chains, one step of them: diff::ForwardSensitivity::advance (JVP) and
  // diff::adjoint's reverse step (VJP), i.e. integrator::multistep_jvp / multistep_vjp on
  // the step's record (one solve on its factorization; with contact through the NCP's
  // modes) and, per rigid body, its 12 x 12 step Jacobian (rigid_bdf2_derivatives.hpp;
  // with rigid bodies in contact the bodies' rows go through the one contact solve, and
  // BDF2's extrapolated states through the extrapolation's Jacobian).
  py::tuple step_jvp(const py::object& dx, const py::object& dv, const py::dict& dtheta, const py::object& dx_prev,
                     const py::object& dv_prev) {
    demand_step_derivative();
    const Eigen::Index n3 = 3L * model_->fem.num_nodes, nr = static_cast<Eigen::Index>(model_->rigid.size());
    const Eigen::Index rows = n3 + 6 * nr;
    const VecX din = vector_or_zero(dx, rows, "dx"), dvin = vector_or_zero(dv, rows, "dv");
    const VecX dxp = vector_or_zero(dx_prev, rows, "dx_prev"), dvp = vector_or_zero(dv_prev, rows, "dv_prev");
    integrator::StepTangent d;
    d.p = VecX::Zero(static_cast<Eigen::Index>(theta_->layout.parameters.size()));
    d.lambda_a = VecX::Zero(static_cast<Eigen::Index>(model_->actuation.actuators.size()));
    VecX drp = VecX::Zero(7 * nr);  // the rigid bodies' mass and inertia tangents, 7 per body
    for (auto item : dtheta) {
      const std::string name = py::str(item.first);
      const diff::ThetaGroup& g = group(name);
      const VecX value = vector_or_zero(py::reinterpret_borrow<py::object>(item.second), g.size, "dtheta['" + name + "']");
      if (name == "actuation") {
        d.lambda_a = value;
      } else if (is_rigid_parameter_group(g)) {
        for (Eigen::Index i = 0; i < g.size; ++i) {
          const auto& p = rigid_parameter_of_column(g.offset + i);
          drp[7 * p.body + p.index] += value[i];
        }
      } else {
        d.p.segment(g.offset, g.size) = value;
      }
    }
    VecX ox = VecX::Zero(rows), ov = VecX::Zero(rows);
    std::string failure;
    {
      py::gil_scoped_release release;
      failure = step_jvp_(din, dvin, dxp, dvp, d, drp, ox, ov);
    }
    if (!failure.empty()) raise(g_step_error, failure, py::dict(py::arg("exit_code") = 1));
    return py::make_tuple(to_numpy(ox, rows), to_numpy(ov, rows));
  }

  py::dict step_vjp(const py::object& bar_x, const py::object& bar_v) {
    demand_step_derivative();
    const Eigen::Index n3 = 3L * model_->fem.num_nodes, nr = static_cast<Eigen::Index>(model_->rigid.size());
    const Eigen::Index rows = n3 + 6 * nr;
    const VecX bx = vector_or_zero(bar_x, rows, "bar_x"), bv = vector_or_zero(bar_v, rows, "bar_v");
    VecX gx(rows), gv(rows), gxp(rows), gvp(rows), gp, ga, grp;
    std::string failure;
    {
      py::gil_scoped_release release;
      failure = step_vjp_(bx, bv, gx, gv, gxp, gvp, gp, ga, grp);
    }
    if (!failure.empty()) raise(g_step_error, failure, py::dict(py::arg("exit_code") = 1));
    py::dict out;
    out["x"] = to_numpy(gx, rows);
    out["v"] = to_numpy(gv, rows);
    out["x_prev"] = to_numpy(gxp, rows);
    out["v_prev"] = to_numpy(gvp, rows);
    for (const auto& g : theta_->groups) {
      if (g.name == "x0" || g.name == "v0") continue;
      if (g.name == "actuation") {
        out[py::str(g.name)] = to_numpy(ga, g.size);
      } else if (is_rigid_parameter_group(g)) {
        VecX col(g.size);
        for (Eigen::Index i = 0; i < g.size; ++i) {
          const auto& p = rigid_parameter_of_column(g.offset + i);
          col[i] = grp.size() ? grp[7 * p.body + p.index] : 0.0;
        }
        out[py::str(g.name)] = to_numpy(col, g.size);
      } else {
        out[py::str(g.name)] = to_numpy(gp.size() ? VecX(gp.segment(g.offset, g.size)) : VecX(), g.size);
      }
    }
    return out;
  }
  // --- end pyrig ---

  // The adjoint's theta: the groups given, else the simulator's jacobian=; `call` is
  // how the error message shows the call.
  diff::ThetaSelection adjoint_theta(const py::object& theta, const char* call) const {
    if (!theta.is_none()) {
      try {
        return diff::parse_theta("theta", theta_list(theta), *model_);
      } catch (const InputError& e) {
        raise(g_scene_error, e.what());
      }
    }
    if (theta_) return *theta_;
    throw py::value_error(std::string("no theta: give ") + call + " or Simulator(scene, jacobian=...)");
  }

  // --- pyrig --- adjoint() of a static scene (issue 23 item 2)
  // l = bar_x . x* (+ bar_rigid . the rigid poses' tangent, 6 per body: position,
  // rotation vector; jacobian()'s rows) at the equilibrium run() solved: dl/dtheta =
  // (dx*/dtheta)^T bar by integrator::static_vjp, the implicit function theorem's
  // transposed solve (one factorization at x*, one solve whatever the number of theta
  // columns; diff::static_jacobian's system). theta as the dynamic adjoint's.
  py::dict adjoint_static(const py::object& bar_x, const py::object& bar_v, const py::object& bar_rigid,
                          const py::object& theta) {
    if (!solved_) throw py::value_error("adjoint(): run() solves the static equilibrium first");
    if (!bar_v.is_none()) throw py::value_error("bar_v: a static equilibrium has no velocities");
    const diff::ThetaSelection selection = adjoint_theta(theta, "adjoint(bar_x=..., theta=\"young, ...\")");
    const Eigen::Index n3 = state_.x.size(), nr = static_cast<Eigen::Index>(model_->rigid.size());
    VecX bar(n3 + 6 * nr);
    bar.head(n3) = vector_or_zero(bar_x, n3, "bar_x");
    bar.tail(6 * nr) = vector_or_zero(bar_rigid, 6 * nr, "bar_rigid (static: 6 per rigid body)");
    integrator::StaticTheta st{selection.layout.parameters, selection.layout.actuation, {}};
    for (const auto& id : selection.layout.rigid_parameters) st.rigid_parameters.emplace_back(id.body, id.index);
    VecX g;
    std::string failure;
    {
      py::gil_scoped_release release;
      use_my_threads();
      try {
        if (!integrator::static_vjp(*model_, *data_, state_, st, bar, g))
          failure = "the derivative of the equilibrium failed (inverted element or tangent not positive definite)";
      } catch (const ComputationError& e) {
        failure = std::string("the derivative of the equilibrium failed: ") + e.what();
      }
    }
    if (!failure.empty()) raise(g_step_error, failure, py::dict(py::arg("exit_code") = 1));
    py::dict out;
    for (const auto& grp : selection.groups)
      out[py::str(grp.name)] = to_numpy(VecX(g.segment(grp.offset, grp.size)), grp.size);
    return out;
  }
  // --- end pyrig ---

  // The gradient of a loss of the state `steps` steps from now, l = bar_x . x_T +
  // bar_v . v_T (+ bar_rigid . the rigid states' tangent), by the adjoint (diff::record,
  // diff::adjoint): a run of its own from the current state on a workspace of its own
  // (the simulator's state and record are unchanged), the reverse sweep recomputing it.
  // theta: groups as jacobian= (default: the simulator's).
  py::dict adjoint(std::optional<long> steps_given, const py::object& bar_x, const py::object& bar_v,
                   const py::object& bar_rigid, const py::object& theta) {
    if (is_static_) {  // pyrig: the equilibrium's adjoint (static scenes: no steps)
      if (steps_given) throw py::value_error("adjoint() of a static scene takes no steps: adjoint(bar_x=...) after run()");
      return adjoint_static(bar_x, bar_v, bar_rigid, theta);
    }
    if (!steps_given) throw py::value_error("adjoint(steps, ...): the number of steps is needed");
    const long steps = *steps_given;
    if (steps < 0) throw py::value_error("steps must be >= 0, got " + std::to_string(steps));
    const diff::ThetaSelection selection = adjoint_theta(theta, "adjoint(..., theta=\"young, ...\")");
    const Eigen::Index n3 = state_.x.size(), nr = static_cast<Eigen::Index>(model_->rigid.size());
    const VecX bx = vector_or_zero(bar_x, n3, "bar_x"), bv = vector_or_zero(bar_v, n3, "bar_v");
    const VecX br = vector_or_zero(bar_rigid, 12 * nr, "bar_rigid");
    diff::Tape tape;
    diff::AdjointResult result;
    std::string failure;
    {
      py::gil_scoped_release release;
      use_my_threads();
      if (!adjoint_data_) adjoint_data_ = std::make_unique<Data>(*model_);
      try {
        StepStatus s = diff::record(*model_, *adjoint_data_, state_, steps, tape);
        if (s.ok()) {
          const auto loss = [&](long k, const State&, VecX& gx, VecX& gv) {
            if (k != steps) return;
            gx += bx;
            gv += bv;
          };
          const auto rigid_loss = [&](long k, const State&, VecX& gr) {
            if (k == steps) gr += br;
          };
          s = diff::adjoint(*model_, *adjoint_data_, tape, selection.layout, loss, result,
                            nr > 0 ? diff::RigidLossCotangent(rigid_loss) : diff::RigidLossCotangent());
        }
        if (!s.ok()) failure = describe(*model_, s);
      } catch (const ComputationError& e) {
        failure = e.what();
      }
    }
    if (!failure.empty()) raise(g_step_error, failure, py::dict(py::arg("exit_code") = 1));
    py::dict out;
    for (const auto& g : selection.groups)
      out[py::str(g.name)] = to_numpy(VecX(result.theta.segment(g.offset, g.size)), g.size);
    // The cotangent of the current state (whether or not theta has x0, v0): soft x, v
    // (3n each), rigid (12 per body: position, rotation vector, velocity, angular velocity).
    out["x"] = to_numpy(result.x0, n3);
    out["v"] = to_numpy(result.v0, n3);
    out["rigid"] = to_numpy(result.rigid0, 12 * nr);
    out["recompute_mismatch"] = result.recompute_mismatch;
    out["x_T"] = to_numpy(tape.frames.back().x, n3);
    out["v_T"] = to_numpy(tape.frames.back().v, n3);
    return out;
  }

  static std::string theta_list(const py::object& theta) {
    if (py::isinstance<py::str>(theta)) return theta.cast<std::string>();
    std::string list;
    for (const auto& name : theta) {
      if (!py::isinstance<py::str>(name)) throw py::type_error("theta: names as strings, e.g. ['young', 'x0']");
      list += (list.empty() ? "" : ",") + name.cast<std::string>();
    }
    return list;
  }

  // The rows of a body in the Jacobians: soft bodies 3 node_begin .. 3 (node_begin + n),
  // rigid body r 3 n_soft + 6 r .. + 6 (position, rotation vector / velocity, angular velocity).
  py::slice rows(const std::string& name) const {
    const int b = soft_index(name);
    if (b >= 0) {
      const auto& body = model_->fem.bodies[static_cast<std::size_t>(b)];
      return py::slice(3L * body.node_begin, 3L * (body.node_begin + body.num_nodes), 1);
    }
    const long start = 3L * model_->fem.num_nodes + 6L * rigid_index(name);
    return py::slice(start, start + 6, 1);
  }

  // One step; raises StepError (the state is left at the last completed step).
  void step() {
    if (is_static_) throw py::value_error(static_whole());
    std::string warning, failure;
    {
      py::gil_scoped_release release;
      failure = advance(warning);
    }
    finish_step(warning, failure, nullptr);
  }

  // `steps` steps: body name -> (steps + 1, n, 3) positions (rigid: (steps + 1, 7)),
  // frame 0 the state before the first step.
  py::dict run(std::optional<long> steps_given) {
    if (is_static_) return run_static(steps_given);
    if (!steps_given) throw py::value_error("run(steps): the number of steps is needed (a static scene's is its load steps)");
    const long steps = *steps_given;
    if (steps < 0) throw py::value_error("steps must be >= 0, got " + std::to_string(steps));
    std::vector<py::array_t<double>> arrays;
    std::vector<double*> buffers;
    py::dict out;
    for (std::size_t b = 0; b < model_->fem.bodies.size(); ++b) {
      const auto& body = model_->fem.bodies[b];
      py::array_t<double> a({static_cast<py::ssize_t>(steps + 1), static_cast<py::ssize_t>(body.num_nodes), py::ssize_t{3}});
      buffers.push_back(a.mutable_data());
      out[py::str(body.name)] = a;
      arrays.push_back(std::move(a));
    }
    for (std::size_t r = 0; r < model_->rigid.size(); ++r) {
      py::array_t<double> a({static_cast<py::ssize_t>(steps + 1), py::ssize_t{7}});
      buffers.push_back(a.mutable_data());
      out[py::str(model_->rigid[r].name)] = a;
      arrays.push_back(std::move(a));
    }
    write_frame(buffers, 0);
    for (long i = 1; i <= steps; ++i) {
      std::string warning, failure;
      {
        py::gil_scoped_release release;
        failure = advance(warning);
        if (failure.empty()) write_frame(buffers, i);
      }
      if (!failure.empty()) {
        // The frames computed so far, as the CLI keeps them in its file.
        py::dict partial;
        for (std::size_t j = 0; j < arrays.size(); ++j)
          partial[py::str(names_[j])] = arrays[j][py::slice(0, static_cast<py::ssize_t>(i), 1)];
        finish_step(warning, failure, &partial);
      }
      finish_step(warning, failure, nullptr);
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();  // Ctrl-C between steps
    }
    return out;
  }

  // A static scene (integrator: static): its equilibrium by the load steps, as
  // cmd_simulate.cpp's static branch (integrator::solve_static, a frame per load step;
  // with theta the implicit function theorem at the equilibrium).
  py::dict run_static(std::optional<long> steps) {
    const long L = model_->step.static_load_steps;
    if (steps && *steps != L)
      throw py::value_error("run(" + std::to_string(*steps) + "): a static scene is solved whole, in its " +
                            std::to_string(L) + " load steps (static.load_steps): run() or run(" + std::to_string(L) + ")");
    if (solved_) throw py::value_error("the static equilibrium is solved already (a new Simulator solves it again)");
    std::vector<py::array_t<double>> arrays;
    std::vector<double*> buffers;
    py::dict out;
    for (const auto& body : model_->fem.bodies) {
      py::array_t<double> a({static_cast<py::ssize_t>(L + 1), static_cast<py::ssize_t>(body.num_nodes), py::ssize_t{3}});
      buffers.push_back(a.mutable_data());
      out[py::str(body.name)] = a;
      arrays.push_back(std::move(a));
    }
    for (const auto& body : model_->rigid) {
      py::array_t<double> a({static_cast<py::ssize_t>(L + 1), py::ssize_t{7}});
      buffers.push_back(a.mutable_data());
      out[py::str(body.name)] = a;
      arrays.push_back(std::move(a));
    }
    write_frame(buffers, 0);
    std::string failure;
    long done = 0;
    {
      py::gil_scoped_release release;
      use_my_threads();
      record_valid_ = false;
      try {
        StepStatus s = integrator::solve_static(*model_, *data_, state_, next_, [&](long k, const State& st) {
          write_frame_of(st, buffers, k);
          done = k;
        });
        if (s.ok() && theta_) {
          const std::string derivative_error =
              diff::static_jacobian(*model_, *data_, next_, theta_->layout, static_jacobian_);
          if (!derivative_error.empty()) {
            s.code = StepStatus::Code::solver_failed;
            s.step = done;
            s.detail = derivative_error;
          }
        }
        if (!s.ok()) failure = describe(*model_, s);
      } catch (const ComputationError& e) {
        failure = e.what();
      } catch (const std::bad_alloc&) {
        failure = "out of memory (an allocation failed)";
      }
    }
    if (!failure.empty()) {
      py::dict partial;
      for (std::size_t j = 0; j < arrays.size(); ++j)
        partial[py::str(names_[j])] = arrays[j][py::slice(0, static_cast<py::ssize_t>(done + 1), 1)];
      py::dict attributes;
      attributes["exit_code"] = 1;
      attributes["steps_done"] = done;
      attributes["time"] = state_.t;
      attributes["trajectory"] = partial;
      raise(g_step_error, failure, attributes);
    }
    state_ = next_;
    k_ = L;
    solved_ = true;
    return out;
  }

  // --- pyrig --- setting the state from Python (issue 23): a restart from that state
  // Soft (n, 3) positions or velocities; rigid (7,) position + unit quaternion w, x, y, z,
  // or (6,) velocity + angular velocity (world): the shapes x() and v() return. The
  // simulator then continues as a new simulator started from its state would: BDF2's
  // next step is its first (implicit Euler, no previous frame), the contact solve has no
  // warm start, no step record (step_jvp/step_vjp need a step), and the forward
  // sensitivities restart at this state (jacobian(): x0, v0 the set state's identity,
  // parameters zero). time and steps_done are kept (sim.time can be set).
  void set_state(const std::string& name, const py::object& values, bool velocity) {
    const char* what = velocity ? "set_v" : "set_x";
    if (is_static_)
      throw py::value_error(std::string(what) + ": a static scene's state is the equilibrium run() solves");
    const auto a = py::array::ensure(values);
    if (!a) throw py::type_error(std::string(what) + ": a numpy array (or a nested list) of float64 values");
    const char kind = a.dtype().kind();
    if (kind != 'f' && kind != 'i' && kind != 'u')
      throw py::type_error(std::string(what) + ": real numbers expected, got dtype " + std::string(py::str(a.dtype())));
    const auto f = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(a);
    const int b = soft_index(name);
    std::vector<py::ssize_t> shape(f.shape(), f.shape() + f.ndim());
    auto shape_text = [&] {
      std::string t = "(";
      for (std::size_t i = 0; i < shape.size(); ++i) t += (i ? ", " : "") + std::to_string(shape[i]);
      return t + (shape.size() == 1 ? ",)" : ")");
    };
    const double* p = f.data();
    for (py::ssize_t i = 0; i < f.size(); ++i)
      if (!std::isfinite(p[i]))
        throw py::value_error(std::string(what) + "('" + name + "'): entry " + std::to_string(i) + " is not finite (" +
                              std::to_string(p[i]) + ")");
    if (b >= 0) {
      const auto& body = model_->fem.bodies[static_cast<std::size_t>(b)];
      for (const auto& part : model_->rigidify.parts)
        if (part.body == b)
          throw py::value_error(std::string(what) + "('" + name + "'): the body has rigidified parts (" + part.name +
                                ": its nodes move as one rigid body); setting its state is not bound in this version (docs/python.md \"Not bound yet\")");
      if (shape != std::vector<py::ssize_t>{body.num_nodes, 3})
        throw py::value_error(std::string(what) + "('" + name + "'): shape (" + std::to_string(body.num_nodes) +
                              ", 3) expected, got " + shape_text());
      VecX& target = velocity ? state_.v : state_.x;
      const Eigen::Index begin = 3L * body.node_begin;
      for (Eigen::Index k = 0; k < 3L * body.num_nodes; ++k) {
        const auto dof = static_cast<std::size_t>(begin + k);
        const double now = velocity ? 0.0 : target[begin + k];
        if (model_->fem.fixed[dof] && p[k] != now)
          throw py::value_error(std::string(what) + "('" + name + "'): node " + std::to_string(k / 3) +
                                " is fixed (its " + "xyz"[k % 3] + " " + (velocity ? "velocity is 0" : "position is " + repr(now)) +
                                "), got " + repr(p[k]));
      }
      target.segment(begin, 3L * body.num_nodes) = Eigen::Map<const VecX>(p, 3L * body.num_nodes);
    } else {
      const int r = rigid_index(name);
      const auto& rb = model_->rigid[static_cast<std::size_t>(r)];
      if (rb.joint.kind != rigid::Joint::Kind::free)
        throw py::value_error(std::string(what) + "('" + name + "'): a rigid body with a joint (hinge, slider or fixed): "
                              "its pose and velocity are constrained by the joint; setting them is not bound in this version (docs/python.md \"Not bound yet\")");
      const py::ssize_t n = velocity ? 6 : 7;
      if (shape != std::vector<py::ssize_t>{n})
        throw py::value_error(std::string(what) + "('" + name + "'): shape (" + std::to_string(n) + ",) expected (" +
                              (velocity ? "velocity, angular velocity" : "position, quaternion w, x, y, z") + "), got " +
                              shape_text());
      auto& rs = state_.rigid[static_cast<std::size_t>(r)];
      if (velocity) {
        rs.velocity = Vec3(p[0], p[1], p[2]);
        rs.angular_velocity = Vec3(p[3], p[4], p[5]);
      } else {
        Eigen::Quaterniond q(p[3], p[4], p[5], p[6]);
        const double norm = q.norm();
        // A unit quaternion to round-off is kept as given (x()'s values round-trip bit
        // for bit); within 1e-6 of unit length it is normalized; otherwise refused.
        if (!(std::abs(norm - 1) <= 1e-6))
          throw py::value_error(std::string(what) + "('" + name + "'): the quaternion (w, x, y, z) must have unit length, "
                                "got |q| = " + repr(norm));
        if (std::abs(norm - 1) > 4e-16) q.normalize();
        rs.position = Vec3(p[0], p[1], p[2]);
        rs.orientation = q;
      }
    }
    restart();
  }
  void set_time(double t) {
    if (!std::isfinite(t)) throw py::value_error("time: a finite number expected, got " + repr(t));
    if (is_static_) throw py::value_error("time: a static scene's time is its load factor");
    state_.t = t;
    restart();
  }
  // `steps` steps in C++ (no frame copied, the GIL released once): the loop of run()
  // without its frames, for long runs and for the overhead figure (docs/performance.md,
  // scripts/bench python). KeyboardInterrupt is seen after the last step.
  void advance_steps(long steps) {
    if (is_static_) throw py::value_error(static_whole());
    if (steps < 0) throw py::value_error("steps must be >= 0, got " + std::to_string(steps));
    std::string warning, failure;
    {
      py::gil_scoped_release release;
      for (long i = 0; i < steps && failure.empty(); ++i) {
        warning.clear();
        failure = advance(warning);
        if (!warning.empty() && failure.empty()) {  // issued now (a failed step's with its error, below)
          py::gil_scoped_acquire acquire;
          warn(warning);
          warning.clear();
        }
      }
    }
    finish_step(warning, failure, nullptr);
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
  }
  // --- end pyrig ---

  // Positions of a body: soft (n, 3) copy; rigid (7,) position + quaternion w, x, y, z.
  py::array_t<double> x(const std::string& name) const {
    const int b = soft_index(name);
    if (b >= 0) {
      const auto& body = model_->fem.bodies[static_cast<std::size_t>(b)];
      return copy_nodes(state_.x.data() + 3L * body.node_begin, body.num_nodes);
    }
    const auto& rs = state_.rigid[static_cast<std::size_t>(rigid_index(name))];
    py::array_t<double> a(py::ssize_t{7});
    pose(rs, a.mutable_data());
    return a;
  }

  // Velocities: soft (n, 3) copy; rigid (6,) velocity of the centre of mass + angular velocity (world).
  py::array_t<double> v(const std::string& name) const {
    const int b = soft_index(name);
    if (b >= 0) {
      const auto& body = model_->fem.bodies[static_cast<std::size_t>(b)];
      return copy_nodes(state_.v.data() + 3L * body.node_begin, body.num_nodes);
    }
    const auto& rs = state_.rigid[static_cast<std::size_t>(rigid_index(name))];
    py::array_t<double> a(py::ssize_t{6});
    double* p = a.mutable_data();
    for (int c = 0; c < 3; ++c) p[c] = rs.velocity[c], p[3 + c] = rs.angular_velocity[c];
    return a;
  }

 private:
  // --- pyrig --- restart bookkeeping (set_x, set_v, time)
  // After a state set from Python: no BDF2 history (the next step is a first step), no
  // contact warm start, no rigid limit restart flag, no step record, sensitivities from here.
  void restart() {
    history_start_ = k_;
    record_valid_ = false;
    data_->contact.previous_keys.clear();  // no key matches: the next NCP starts from zero forces
    data_->contact.previous_lambda.resize(0);
    data_->contact.rigid.limit_lambda.resize(0);  // the joint limits' warm start (as a fresh Data's)
    for (auto& info : data_->rigid) info.at_limit = false;
    if (sensitivity_) sensitivity_ = std::make_unique<diff::ForwardSensitivity>(*model_, theta_->layout);
  }
  static std::string repr(double v) {
    std::ostringstream s;
    s.precision(17);
    s << v;
    return s.str();
  }
  long history_start_ = 0;  // k_ at the last restart: the step k_ + 1 after it has no previous frame
  // --- end pyrig ---
  // --- pyrig --- step_jvp / step_vjp's computation (without the GIL) and helpers
  bool is_rigid_parameter_group(const diff::ThetaGroup& g) const {
    return !theta_->layout.rigid_parameters.empty() && g.offset >= theta_->layout.rigid_parameter_offset(*model_);
  }
  const rigid::RigidParameterId& rigid_parameter_of_column(Eigen::Index column) const {
    return theta_->layout.rigid_parameters[static_cast<std::size_t>(column - theta_->layout.rigid_parameter_offset(*model_))];
  }
  // The state before the last step's input (BDF2's x_{n-1}), when the step used it
  // (data.history_weight != 0): advance()'s swaps leave it in next_ until the next step.
  const State* step_previous() const { return data_->history_weight != 0 ? &next_ : nullptr; }
  // Each rigid body's Jacobian of the last step (or, in contact, of its BDF2
  // extrapolation), as diff::ForwardSensitivity::advance and diff::adjoint form it.
  void rigid_step_jacobians() {
    const State& in = previous_;
    const State* prev = step_previous();
    const bool coupled = model_->contact.with_rigid(), rigid_bdf2 = model_->step.integrator == IntegratorKind::bdf2;
    rigid_J_.resize(model_->rigid.size());
    for (std::size_t r = 0; r < model_->rigid.size(); ++r) {
      auto& J = rigid_J_[r];
      if (!coupled) {
        const bool hat = rigid_bdf2 && data_->hat.rigid.size() == model_->rigid.size();
        rigid::bdf2_step_jacobian(model_->rigid[r], in.rigid[r], rigid_bdf2 && prev ? &prev->rigid[r] : nullptr,
                                  hat ? data_->hat.rigid[r] : in.rigid[r], state_.rigid[r], data_->rigid[r],
                                  model_->step.dt, model_->step.gravity, J);
      } else if (prev) {
        J.bdf2 = true;
        rigid::extrapolation_jacobian(model_->rigid[r], in.rigid[r], prev->rigid[r], data_->hat.rigid[r], J.extrapolation);
      } else {
        J.bdf2 = false;
      }
    }
  }
  static constexpr const char* kDerivativeFailed =
      "failed (a linear solve did not succeed or gave non-finite values)";
  std::string step_jvp_(const VecX& din, const VecX& dvin, const VecX& dxp, const VecX& dvp,
                        integrator::StepTangent& d, const VecX& drp, VecX& ox, VecX& ov) {
    use_my_threads();
    const Eigen::Index n3 = 3L * model_->fem.num_nodes, nr = static_cast<Eigen::Index>(model_->rigid.size());
    const bool coupled = model_->contact.with_rigid();
    const State* prev = step_previous();
    try {
      rigid_step_jacobians();
      d.x = din.head(n3);
      d.v = dvin.head(n3);
      integrator::StateTangent d_prev, out;
      if (prev) {
        d_prev.x = dxp.head(n3);
        d_prev.v = dvp.head(n3);
      }
      if (coupled) {
        // The bodies' rows go through the step's contact solve; BDF2: as the tangent of
        // their extrapolated states.
        d.rigid.resize(12 * nr);
        d.rigid_p = drp;
        for (Eigen::Index r = 0; r < nr; ++r) {
          rigid::Vec12 d_n;
          d_n << din.segment<6>(n3 + 6 * r), dvin.segment<6>(n3 + 6 * r);
          const auto& J = rigid_J_[static_cast<std::size_t>(r)];
          if (prev && J.bdf2) {
            rigid::Vec12 d_p;
            d_p << dxp.segment<6>(n3 + 6 * r), dvp.segment<6>(n3 + 6 * r);
            d_n = (J.extrapolation.in * d_n + J.extrapolation.previous * d_p +
                   J.extrapolation.params * drp.segment<7>(7 * r)).eval();
          }
          d.rigid.segment<12>(12 * r) = d_n;
        }
      }
      if (n3 > 0 || coupled) {
        if (!integrator::multistep_jvp(*step_derivatives_, *model_, *data_, state_, d, d_prev, out, &previous_, prev))
          return "the derivative of step " + std::to_string(k_) + " " + kDerivativeFailed;
        if (out.x.size()) ox.head(n3) = out.x;
        if (out.v.size()) ov.head(n3) = out.v;
      }
      for (Eigen::Index r = 0; r < nr; ++r) {
        rigid::Vec12 d_out;
        if (coupled) {
          d_out = out.rigid.size() ? rigid::Vec12(out.rigid.segment<12>(12 * r)) : rigid::Vec12::Zero();
        } else {
          const auto& J = rigid_J_[static_cast<std::size_t>(r)];
          rigid::Vec12 d_in, d_p;
          d_in << din.segment<6>(n3 + 6 * r), dvin.segment<6>(n3 + 6 * r);
          d_out = J.state * d_in + J.params * drp.segment<7>(7 * r);
          if (J.bdf2) {
            d_p << dxp.segment<6>(n3 + 6 * r), dvp.segment<6>(n3 + 6 * r);
            d_out += J.previous * d_p;
          }
        }
        ox.segment<6>(n3 + 6 * r) = d_out.head<6>();
        ov.segment<6>(n3 + 6 * r) = d_out.tail<6>();
      }
    } catch (const ComputationError& e) {
      return "the derivative of step " + std::to_string(k_) + " failed: " + e.what();
    } catch (const std::invalid_argument& e) {
      return "the derivative of step " + std::to_string(k_) + " failed: " + e.what();
    }
    if (!ox.allFinite() || !ov.allFinite()) return "the derivative of step " + std::to_string(k_) + " gave non-finite values";
    return "";
  }
  std::string step_vjp_(const VecX& bx, const VecX& bv, VecX& gx, VecX& gv, VecX& gxp, VecX& gvp, VecX& gp, VecX& ga,
                        VecX& grp) {
    use_my_threads();
    const Eigen::Index n3 = 3L * model_->fem.num_nodes, nr = static_cast<Eigen::Index>(model_->rigid.size());
    const bool coupled = model_->contact.with_rigid();
    const State* prev = step_previous();
    gx.setZero(), gv.setZero(), gxp.setZero(), gvp.setZero();
    gp = VecX::Zero(static_cast<Eigen::Index>(theta_->layout.parameters.size()));
    ga = VecX::Zero(static_cast<Eigen::Index>(model_->actuation.actuators.size()));
    grp = VecX::Zero(7 * nr);
    try {
      rigid_step_jacobians();
      if (n3 > 0 || coupled) {
        integrator::StateTangent bar, bar_prev;
        integrator::StepCotangent cot;
        bar.x = bx.head(n3);
        bar.v = bv.head(n3);
        if (coupled) {
          bar.rigid.resize(12 * nr);
          for (Eigen::Index r = 0; r < nr; ++r)
            bar.rigid.segment<12>(12 * r) << bx.segment<6>(n3 + 6 * r), bv.segment<6>(n3 + 6 * r);
        }
        if (!integrator::multistep_vjp(*step_derivatives_, *model_, *data_, state_, bar, cot, bar_prev, &previous_, prev))
          return "the derivative of step " + std::to_string(k_) + " " + kDerivativeFailed;
        if (cot.x.size()) gx.head(n3) = cot.x;
        if (cot.v.size()) gv.head(n3) = cot.v;
        if (bar_prev.x.size()) gxp.head(n3) = bar_prev.x;
        if (bar_prev.v.size()) gvp.head(n3) = bar_prev.v;
        if (cot.p.size()) gp = cot.p;
        if (cot.lambda_a.size()) ga = cot.lambda_a;
        if (coupled) {
          if (cot.rigid_p.size()) grp = cot.rigid_p;
          for (Eigen::Index r = 0; r < nr; ++r) {
            const rigid::Vec12 bar_hat = cot.rigid.size() ? rigid::Vec12(cot.rigid.segment<12>(12 * r)) : rigid::Vec12::Zero();
            rigid::Vec12 b_in = bar_hat, b_prev = rigid::Vec12::Zero();
            const auto& J = rigid_J_[static_cast<std::size_t>(r)];
            if (prev && J.bdf2) {  // split the extrapolated state's cotangent (diff::adjoint)
              b_in = J.extrapolation.in.transpose() * bar_hat;
              b_prev = J.extrapolation.previous.transpose() * bar_hat;
              grp.segment<7>(7 * r) += J.extrapolation.params.transpose() * bar_hat;
            }
            gx.segment<6>(n3 + 6 * r) = b_in.head<6>(), gv.segment<6>(n3 + 6 * r) = b_in.tail<6>();
            gxp.segment<6>(n3 + 6 * r) = b_prev.head<6>(), gvp.segment<6>(n3 + 6 * r) = b_prev.tail<6>();
          }
        }
      }
      for (Eigen::Index r = 0; !coupled && r < nr; ++r) {
        const auto& J = rigid_J_[static_cast<std::size_t>(r)];
        rigid::Vec12 bar_out;
        bar_out << bx.segment<6>(n3 + 6 * r), bv.segment<6>(n3 + 6 * r);
        const rigid::Vec12 b_in = J.state.transpose() * bar_out;
        grp.segment<7>(7 * r) += J.params.transpose() * bar_out;
        gx.segment<6>(n3 + 6 * r) = b_in.head<6>(), gv.segment<6>(n3 + 6 * r) = b_in.tail<6>();
        if (J.bdf2) {
          const rigid::Vec12 b_prev = J.previous.transpose() * bar_out;
          gxp.segment<6>(n3 + 6 * r) = b_prev.head<6>(), gvp.segment<6>(n3 + 6 * r) = b_prev.tail<6>();
        }
      }
    } catch (const ComputationError& e) {
      return "the derivative of step " + std::to_string(k_) + " failed: " + e.what();
    } catch (const std::invalid_argument& e) {
      return "the derivative of step " + std::to_string(k_) + " failed: " + e.what();
    }
    if (!gx.allFinite() || !gv.allFinite() || !gxp.allFinite() || !gvp.allFinite() || !gp.allFinite() ||
        !ga.allFinite() || !grp.allFinite())
      return "the derivative of step " + std::to_string(k_) + " gave non-finite values";
    return "";
  }
  std::vector<rigid::Bdf2StepJacobian> rigid_J_;  // step_jvp/step_vjp: the last step's, per rigid body
  // --- end pyrig ---

  int soft_index(const std::string& name) const {
    for (std::size_t b = 0; b < model_->fem.bodies.size(); ++b)
      if (model_->fem.bodies[b].name == name) return static_cast<int>(b);
    return -1;
  }
  int rigid_index(const std::string& name) const {
    for (std::size_t r = 0; r < model_->rigid.size(); ++r)
      if (model_->rigid[r].name == name) return static_cast<int>(r);
    std::string known;
    for (const auto& n : names_) known += (known.empty() ? "" : ", ") + n;
    throw py::key_error("no body '" + name + "' in the scene (bodies: " + known + ")");
  }
  // The thread plan is process-wide: another simulator may have set its own since.
  void use_my_threads() const {
    if (plan_threads() != plan_threads_) set_threads(threads_);
  }
  void demand_step_derivative() {
    if (!theta_) throw py::value_error("no theta: give Simulator(scene, jacobian=\"young, ...\") first");
    if (is_static_)
      raise(g_scene_error, "step_jvp/step_vjp: a static scene (integrator: static) has no time step; jacobian() and "
                           "adjoint() after run() give d x* / d theta");  // pyrig: SceneError (a ValueError)
    if (!record_valid_) throw py::value_error("no step to differentiate: step() first (a failed step leaves none)");
    if (!step_derivatives_) step_derivatives_ = std::make_unique<integrator::StepDerivatives>(*model_, theta_->layout.parameters);
  }
  const diff::ThetaGroup& group(const std::string& name) const {
    for (const auto& g : theta_->groups)
      if (g.name == name) {
        if (name == "x0" || name == "v0")
          throw py::key_error("dtheta['" + name + "']: the step's input state is dx, dv");
        return g;
      }
    throw py::key_error("dtheta: '" + name + "' is not one of the simulator's theta groups");
  }
  static VecX vector_or_zero(const py::object& o, Eigen::Index n, const std::string& what) {
    if (o.is_none()) return VecX::Zero(n);
    const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(o);
    if (!a) throw py::type_error(what + ": an array of numbers");
    if (a.size() != n)
      throw py::value_error(what + ": " + std::to_string(n) + " values expected, got " + std::to_string(a.size()));
    return Eigen::Map<const VecX>(a.data(), n);
  }
  static py::array_t<double> to_numpy(const VecX& v, Eigen::Index n) {
    py::array_t<double> a(static_cast<py::ssize_t>(n));
    if (v.size() == n)
      std::memcpy(a.mutable_data(), v.data(), sizeof(double) * static_cast<std::size_t>(n));
    else
      std::fill(a.mutable_data(), a.mutable_data() + n, 0.0);  // an empty cotangent: zero
    return a;
  }
  static py::array_t<double> copy_nodes(const double* src, int n) {
    py::array_t<double> a({static_cast<py::ssize_t>(n), py::ssize_t{3}});
    std::memcpy(a.mutable_data(), src, sizeof(double) * 3 * static_cast<std::size_t>(n));
    return a;
  }
  static void pose(const rigid::RigidState& rs, double* p) {
    for (int c = 0; c < 3; ++c) p[c] = rs.position[c];
    p[3] = rs.orientation.w(), p[4] = rs.orientation.x(), p[5] = rs.orientation.y(), p[6] = rs.orientation.z();
  }
  // Frame i of run()'s arrays (without the GIL: plain memory of arrays kept alive by run()).
  void write_frame(const std::vector<double*>& buffers, long i) const { write_frame_of(state_, buffers, i); }
  void write_frame_of(const State& st, const std::vector<double*>& buffers, long i) const {
    std::size_t j = 0;
    for (const auto& body : model_->fem.bodies) {
      const std::size_t count = 3 * static_cast<std::size_t>(body.num_nodes);
      std::memcpy(buffers[j++] + static_cast<std::size_t>(i) * count, st.x.data() + 3L * body.node_begin,
                  sizeof(double) * count);
    }
    for (const auto& rs : st.rigid) pose(rs, buffers[j++] + 7 * i);
  }
  std::string static_whole() const {
    return "a static scene (integrator: static) is solved whole: run() solves its equilibrium in its " +
           std::to_string(model_->step.static_load_steps) + " load steps";
  }

  // The step of cmd_simulate.cpp's loop, without the GIL: "" or the failure's message;
  // `warning`: a non-convergence warning to issue (non-strict).
  std::string advance(std::string& warning) {
    use_my_threads();
    const long k = k_ + 1;
    record_valid_ = false;  // data is about to hold this step's record
    StepStatus s;
    try {
      s = integrator::time_step(*model_, *data_, state_, k > history_start_ + 1 ? &previous_ : nullptr, next_, k);  // pyrig: history_start_
    } catch (const ComputationError& e) {
      return e.what();
    } catch (const std::bad_alloc&) {
      return "out of memory (an allocation failed)";
    }
    if (s.code == StepStatus::Code::not_converged) {
      if (strict_) return describe(*model_, s);
      ++newton_not_converged_;
      warning = describe(*model_, s);
      s = StepStatus{};
    } else if (!s.ok()) {
      return describe(*model_, s);
    }
    if (model_->contact.enabled) {
      if (const StepStatus c = integrator::contact_status(*model_, *data_, k); !c.ok()) {
        if (strict_) return describe(*model_, c);
        ++contact_not_converged_;
        warning = describe(*model_, c) + " (strict=True makes it an error)";
      }
    }
    if (sensitivity_) {
      // The forward sensitivities through the step, as cmd_simulate.cpp carries them; a
      // failed derivative is the step's failure, with the CLI's message.
      std::string derivative_error;
      bool derivative_ok = false;
      try {
        derivative_ok = sensitivity_->advance(*model_, *data_, state_, next_);
      } catch (const ComputationError& e) {
        derivative_error = e.what();
      }
      if (!derivative_ok) {
        StepStatus f;
        f.code = StepStatus::Code::solver_failed;
        f.step = k;
        f.detail = derivative_error.empty()
                       ? "the derivative of the step failed (a linear solve did not succeed or gave non-finite values)"
                       : "the derivative of the step failed: " + derivative_error;
        return describe(*model_, f);
      }
    }
    std::swap(previous_, state_);  // BDF2's history (and the input state of step_jvp/step_vjp)
    std::swap(state_, next_);
    k_ = k;
    record_valid_ = true;
    return "";
  }

  // With the GIL: issue the warning, raise StepError on a failure (with the frames
  // computed so far as `trajectory` when run() failed).
  void finish_step(const std::string& warning, const std::string& failure, const py::dict* partial) {
    if (!warning.empty()) warn(warning);
    if (failure.empty()) return;
    py::dict attributes;
    attributes["exit_code"] = 1;
    attributes["steps_done"] = k_;
    attributes["time"] = state_.t;
    if (partial) attributes["trajectory"] = *partial;
    raise(g_step_error, failure, attributes);
  }

  static void warn(const std::string& message, PyObject* category = g_convergence_warning) {
    if (PyErr_WarnEx(category, message.c_str(), 1) != 0) throw py::error_already_set();
  }

  int threads_;
  int plan_threads_ = 1;  // the OpenMP threads set_threads(threads_) gave
  bool strict_;
  std::unique_ptr<Model> model_;  // a fixed address: Data and the step refer to it
  std::unique_ptr<Data> data_;
  std::optional<diff::ThetaSelection> theta_;
  std::unique_ptr<diff::ForwardSensitivity> sensitivity_;
  std::unique_ptr<integrator::StepDerivatives> step_derivatives_;  // step_jvp/step_vjp (made on first use)
  bool record_valid_ = false;
  bool is_static_ = false, solved_ = false;  // static scenes: run() solves the equilibrium once
  MatX static_jacobian_;                     // static: d x* / d theta
  std::unique_ptr<Data> adjoint_data_;  // adjoint()'s workspace (made on first use)  // data holds the record of the step previous_ -> state_
  State state_, next_, previous_;
  long k_ = 0;  // steps done
  long newton_not_converged_ = 0, contact_not_converged_ = 0;
  std::vector<std::string> names_;  // soft bodies, then rigid bodies (run()'s order)
};

// --- torch support (ptorch) ---
// softdiff.Rollout: the runs and adjoints that softdiff.torch (python/softdiff/torch.py,
// docs/python.md "PyTorch") differentiates. A model of its own (a copy of the scene's,
// `base_`) whose parameters are set per run, and one Data workspace restarted before
// every run and every reverse sweep (Data::restart: a fresh workspace, symbolic
// analysis kept), as calibration's workspace does (optim/calibration.cpp).
//   record(steps, values, actuation, x0, v0) -> (x, v, recording): a trajectory with the
//     theta values and a per-step actuation sequence (steps x n_a, each actuator's own
//     value: cable tension (N), pressure (Pa), servo force (N) or torque (N m), replacing
//     its schedule), recorded on a diff::Tape kept in `recording`.
//   adjoint(recording, bar_x, bar_v) -> dict: the reverse sweep (diff::adjoint) over that
//     recording for l = sum_k bar_x[k] . x_k + bar_v[k] . v_k (a cotangent per frame),
//     with the model set back to the recording's values: dl/dtheta, dl/d(actuation
//     sequence) (AdjointResult::lambda_a), dl/dx0, dl/dv0, recompute_mismatch.
// The record loop is diff::record's (lib/softdiff/diff/trajectory.cpp) with the
// simulator's contact policy added per step (a ConvergenceWarning, or with strict a
// StepError); a Newton solve that misses its tolerance is a StepError (diff::adjoint
// cannot recompute such a step: it stops on its status). Soft bodies only, implicit
// Euler or BDF2; rigid bodies and static scenes are refused (issue 23).
struct Recording {
  diff::Tape tape;
  VecX values;            // theta's values of the run (theta column order)
  VecX x0, v0;            // the initial state of the run
  long contact_not_converged = 0;
  long id = 0;            // the run's number in its Rollout
  long owner = 0;         // the serial number of the Rollout that recorded it
};

class Rollout {
  // The GIL is released during runs and sweeps, which use the one workspace: a second
  // Python thread calling in meanwhile is refused (RuntimeError), not raced.
  struct Busy {
    explicit Busy(bool& flag) : flag_(flag) {
      if (flag_) throw std::runtime_error("Rollout: in use by another thread (one workspace: one run or sweep at a time; "
                                          "make a Rollout per thread)");
      flag_ = true;
    }
    ~Busy() { flag_ = false; }
    Busy(const Busy&) = delete;
    Busy& operator=(const Busy&) = delete;
    bool& flag_;
  };

 public:
  Rollout(const Scene& scene, const py::object& theta, int threads, bool strict) : threads_(threads), strict_(strict) {
    if (threads < 0) throw py::value_error("threads must be >= 0 (0: all cores), got " + std::to_string(threads));
    io::BuildReport report;
    report.strict = strict;
    try {
      py::gil_scoped_release release;
      plan_threads_ = set_threads(threads_).threads;
      base_ = std::make_unique<Model>(io::build_model(scene.desc, &report));
    } catch (const InputError& e) {
      raise(g_scene_error, e.what());
    } catch (const ComputationError& e) {
      raise(g_step_error, e.what());
    }
    for (const auto& w : report.warnings)
      if (PyErr_WarnEx(g_scene_warning, w.c_str(), 1) != 0) throw py::error_already_set();
    if (base_->step.integrator == IntegratorKind::static_equilibrium)
      throw py::value_error("Rollout: a static scene (integrator: static) has no trajectory to differentiate; not bound "
                            "yet (docs/python.md \"Not bound yet\"): Simulator.jacobian() after run() gives d x* / d theta");
    if (!base_->rigid.empty())
      throw py::value_error("Rollout: scenes with rigid bodies are not bound yet (docs/python.md \"Not bound yet\"): the torch interop "
                            "differentiates soft bodies' node trajectories; Simulator.adjoint() covers rigid bodies");
    if (!theta.is_none()) {
      std::string list;
      if (py::isinstance<py::str>(theta)) {
        list = theta.cast<std::string>();
      } else {
        for (const auto& name : theta) {
          if (!py::isinstance<py::str>(name)) throw py::type_error("theta: names as strings, e.g. ['young', 'poisson']");
          list += (list.empty() ? "" : ",") + name.cast<std::string>();
        }
      }
      if (!list.empty()) {
        try {
          selection_ = diff::parse_theta("theta", list, *base_);
        } catch (const InputError& e) {
          raise(g_scene_error, e.what());
        }
        for (const auto& g : selection_.groups)
          if (g.name == "actuation" || g.name == "x0" || g.name == "v0" || g.name == "mass" || g.name == "inertia")
            throw py::value_error("Rollout: theta '" + g.name + "': theta holds material parameters (young, poisson, "
                                  "density, rayleigh_mass, rayleigh_stiffness, friction); the actuation sequence is "
                                  "record()'s `actuation`, the initial state its x0, v0");
      }
    }
    for (const auto& p : selection_.layout.parameters) friction_ = friction_ || p.kind == Parameter::friction;
    model_ = std::make_unique<Model>(*base_);
    data_ = std::make_unique<Data>(*model_);
    n3_ = 3L * base_->fem.num_nodes;
  }

  long num_nodes() const { return base_->fem.num_nodes; }
  long num_actuators() const { return static_cast<long>(base_->actuation.actuators.size()); }
  double dt() const { return base_->step.dt; }
  std::vector<std::string> actuators() const {
    std::vector<std::string> out;
    for (const auto& a : base_->actuation.actuators) out.push_back(a.name);
    return out;
  }
  std::vector<std::string> theta_columns() const {
    std::vector<std::string> out;
    for (const auto& g : selection_.groups) out.insert(out.end(), g.columns.begin(), g.columns.end());
    return out;
  }
  std::vector<std::string> theta_groups() const {
    std::vector<std::string> out;
    for (const auto& g : selection_.groups) out.push_back(g.name);
    return out;
  }
  // The scene's values of theta's columns (diff::get_parameter).
  VecX scene_values() const {
    const auto& ps = selection_.layout.parameters;
    VecX v(static_cast<Eigen::Index>(ps.size()));
    for (std::size_t j = 0; j < ps.size(); ++j) v[static_cast<Eigen::Index>(j)] = diff::get_parameter(*base_, ps[j]);
    return v;
  }
  py::array_t<double> theta_values() const {
    const VecX v = scene_values();
    py::array_t<double> a(static_cast<py::ssize_t>(v.size()));
    if (v.size()) std::memcpy(a.mutable_data(), v.data(), sizeof(double) * static_cast<std::size_t>(v.size()));
    return a;
  }
  // The actuators' scheduled values of steps 1..steps, (steps, n_a): lambda_a(t_k) at the
  // end of each step, t_k = t_{k-1} + dt as the step computes it (implicit_euler.cpp).
  py::array_t<double> schedule(long steps) const {
    if (steps < 0) throw py::value_error("steps must be >= 0, got " + std::to_string(steps));
    const Eigen::Index na = static_cast<Eigen::Index>(base_->actuation.actuators.size());
    py::array_t<double> a({static_cast<py::ssize_t>(steps), static_cast<py::ssize_t>(na)});
    VecX lambda(na);
    double t = base_->initial.t;
    for (long k = 0; k < steps; ++k) {
      t = t + base_->step.dt;
      base_->actuation.values(t, lambda);
      for (Eigen::Index i = 0; i < na; ++i) a.mutable_data()[k * na + i] = lambda[i];
    }
    return a;
  }
  // An effector's embedding: (global node indices, weights), p = sum_a w_a x[nodes[a]].
  py::tuple effector(const std::string& name) const {
    std::string known;
    for (const auto& e : base_->actuation.effectors) {
      if (e.name == name) {
        const auto& pt = e.effector.point();
        py::array_t<long> nodes(static_cast<py::ssize_t>(pt.count));
        py::array_t<double> w(static_cast<py::ssize_t>(pt.count));
        for (int i = 0; i < pt.count; ++i) nodes.mutable_data()[i] = pt.nodes[static_cast<std::size_t>(i)], w.mutable_data()[i] = pt.w[i];
        return py::make_tuple(nodes, w);
      }
      known += (known.empty() ? "" : ", ") + e.name;
    }
    throw py::key_error("no effector '" + name + "' in the scene (effectors: " + (known.empty() ? "none" : known) + ")");
  }
  // A soft body's nodes in the trajectory's node axis.
  py::slice nodes(const std::string& name) const {
    std::string known;
    for (const auto& b : base_->fem.bodies) {
      if (b.name == name) return py::slice(b.node_begin, b.node_begin + b.num_nodes, 1);
      known += (known.empty() ? "" : ", ") + b.name;
    }
    throw py::key_error("no soft body '" + name + "' in the scene (bodies: " + known + ")");
  }

  py::tuple record(long steps, const py::object& values, const py::object& actuation, const py::object& x0,
                   const py::object& v0) {
    if (steps < 0) throw py::value_error("steps must be >= 0, got " + std::to_string(steps));
    auto rec = std::make_shared<Recording>();
    const auto k = static_cast<Eigen::Index>(selection_.layout.parameters.size());
    rec->values = values.is_none() ? scene_values() : array(values, k, "values");
    const Eigen::Index na = static_cast<Eigen::Index>(base_->actuation.actuators.size());
    MatX lambda;  // (n_a x steps), empty: the schedules
    if (!actuation.is_none()) {
      const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(actuation);
      if (!a) throw py::type_error("actuation: an array of numbers (steps, n_actuators)");
      if (a.ndim() != 2 || a.shape(0) != steps || a.shape(1) != na)
        throw py::value_error("actuation: shape (" + std::to_string(steps) + ", " + std::to_string(na) +
                              ") expected (steps, n_actuators), got " + shape_text(a));
      lambda = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(a.data(), steps, na)
                   .transpose();
      if (!lambda.allFinite()) throw py::value_error("actuation: a value is not finite");
    }
    rec->x0 = x0.is_none() ? VecX(base_->initial.x) : array(x0, n3_, "x0");
    rec->v0 = v0.is_none() ? VecX(base_->initial.v) : array(v0, n3_, "v0");
    std::string failure, set_error;
    std::vector<std::string> warnings;
    {
      const Busy busy(busy_);  // taken with the GIL held
      py::gil_scoped_release release;
      use_my_threads();
      set_error = set_values(rec->values);
      if (set_error.empty()) failure = run(steps, lambda, *rec, warnings);
    }
    if (!set_error.empty()) throw py::value_error(set_error);
    for (const auto& w : warnings)
      if (PyErr_WarnEx(g_convergence_warning, w.c_str(), 1) != 0) throw py::error_already_set();
    if (!failure.empty()) {
      py::dict attributes;
      attributes["exit_code"] = 1;
      attributes["steps_done"] = rec->tape.steps();
      raise(g_step_error, failure, attributes);
    }
    rec->id = ++runs_;
    rec->owner = serial_;
    py::array_t<double> x({static_cast<py::ssize_t>(steps + 1), static_cast<py::ssize_t>(base_->fem.num_nodes), py::ssize_t{3}});
    py::array_t<double> v({static_cast<py::ssize_t>(steps + 1), static_cast<py::ssize_t>(base_->fem.num_nodes), py::ssize_t{3}});
    for (long f = 0; f <= steps; ++f) {
      const State& s = rec->tape.frames[static_cast<std::size_t>(f)];
      std::memcpy(x.mutable_data() + f * n3_, s.x.data(), sizeof(double) * static_cast<std::size_t>(n3_));
      std::memcpy(v.mutable_data() + f * n3_, s.v.data(), sizeof(double) * static_cast<std::size_t>(n3_));
    }
    return py::make_tuple(x, v, rec);
  }

  py::dict adjoint(const std::shared_ptr<Recording>& rec, const py::object& bar_x, const py::object& bar_v) {
    if (!rec) throw py::type_error("adjoint: a Recording from record()");
    if (rec->owner != serial_) throw py::value_error("adjoint: the recording is another Rollout's (record() it with this one)");
    const long T = rec->tape.steps();
    const std::size_t frames = static_cast<std::size_t>(T + 1);
    const auto cotangent = [&](const py::object& o, const char* what) {
      MatX c;  // (3n x T + 1), empty: zero
      if (o.is_none()) return c;
      const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(o);
      if (!a) throw py::type_error(std::string(what) + ": an array of numbers (steps + 1, n, 3)");
      if (a.size() != static_cast<py::ssize_t>(frames) * n3_ || a.ndim() < 1 || a.shape(0) != static_cast<py::ssize_t>(frames))
        throw py::value_error(std::string(what) + ": shape (" + std::to_string(T + 1) + ", " + std::to_string(n3_ / 3) +
                              ", 3) expected (a cotangent per frame), got " + shape_text(a));
      c = Eigen::Map<const MatX>(a.data(), n3_, static_cast<Eigen::Index>(frames));
      if (!c.allFinite()) throw py::value_error(std::string(what) + ": a value is not finite");
      return c;
    };
    const MatX bx = cotangent(bar_x, "bar_x"), bv = cotangent(bar_v, "bar_v");
    diff::AdjointResult result;
    std::string failure, set_error;
    {
      const Busy busy(busy_);
      py::gil_scoped_release release;
      use_my_threads();
      set_error = set_values(rec->values);  // the recording's model, bit for bit (restore, then set)
      if (set_error.empty()) {
        const auto loss = [&](long k, const State&, VecX& gx, VecX& gv) {
          if (bx.size()) gx += bx.col(k);
          if (bv.size()) gv += bv.col(k);
        };
        try {
          const StepStatus s = diff::adjoint(*model_, *data_, rec->tape, selection_.layout, loss, result);
          if (!s.ok()) failure = describe(*model_, s);
        } catch (const ComputationError& e) {
          failure = e.what();
        }
      }
    }
    if (!set_error.empty()) throw py::value_error(set_error);
    if (!failure.empty()) raise(g_step_error, "adjoint: " + failure, py::dict(py::arg("exit_code") = 1));
    if (!result.theta.allFinite() || !result.lambda_a.allFinite() || !result.x0.allFinite() || !result.v0.allFinite())
      raise(g_step_error, "adjoint: the gradient has non-finite entries", py::dict(py::arg("exit_code") = 1));
    py::dict out;
    const auto k = static_cast<Eigen::Index>(selection_.layout.parameters.size());
    py::array_t<double> theta(static_cast<py::ssize_t>(k));
    if (k) std::memcpy(theta.mutable_data(), result.theta.data(), sizeof(double) * static_cast<std::size_t>(k));
    out["theta"] = theta;
    const Eigen::Index na = result.lambda_a.rows();
    py::array_t<double> act({static_cast<py::ssize_t>(T), static_cast<py::ssize_t>(na)});
    for (long s = 0; s < T; ++s)
      for (Eigen::Index i = 0; i < na; ++i) act.mutable_data()[s * na + i] = result.lambda_a(i, s);
    out["actuation"] = act;
    py::array_t<double> gx({static_cast<py::ssize_t>(n3_ / 3), py::ssize_t{3}}), gv({static_cast<py::ssize_t>(n3_ / 3), py::ssize_t{3}});
    std::memcpy(gx.mutable_data(), result.x0.data(), sizeof(double) * static_cast<std::size_t>(n3_));
    std::memcpy(gv.mutable_data(), result.v0.data(), sizeof(double) * static_cast<std::size_t>(n3_));
    out["x0"] = gx;
    out["v0"] = gv;
    out["recompute_mismatch"] = result.recompute_mismatch;
    return out;
  }

 private:
  static std::string shape_text(const py::array& a) {
    std::string s = "(";
    for (py::ssize_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
    return s + (a.ndim() == 1 ? ",)" : ")");
  }
  static VecX array(const py::object& o, Eigen::Index n, const std::string& what) {
    const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(o);
    if (!a) throw py::type_error(what + ": an array of numbers");
    if (a.size() != n)
      throw py::value_error(what + ": " + std::to_string(n) + " values expected, got " + std::to_string(a.size()));
    VecX v = Eigen::Map<const VecX>(a.data(), n);
    if (!v.allFinite()) throw py::value_error(what + ": a value is not finite");
    return v;
  }
  void use_my_threads() const {
    if (plan_threads() != plan_threads_) set_threads(threads_);
  }
  // The model at `values`: every theta parameter back to the scene's value, then set in
  // order (the same model, bit for bit, as set on a fresh copy: diff/parameters.hpp), and
  // the workspace restarted. "" or why a value was refused (its range).
  std::string set_values(const VecX& values) {
    const auto& ps = selection_.layout.parameters;
    for (const auto& p : ps) diff::restore_parameter(*model_, *base_, p);
    try {
      for (std::size_t j = 0; j < ps.size(); ++j) diff::set_parameter(*model_, ps[j], values[static_cast<Eigen::Index>(j)]);
    } catch (const std::invalid_argument& e) {
      for (const auto& p : ps) diff::restore_parameter(*model_, *base_, p);
      data_->restart(*model_, friction_);
      return std::string("values: ") + e.what();
    }
    data_->restart(*model_, friction_);
    return "";
  }
  // diff::record's loop (trajectory.cpp), with the contact policy of Simulator::advance.
  std::string run(long steps, const MatX& actuation, Recording& rec, std::vector<std::string>& warnings) {
    State initial = model_->initial;
    initial.x = rec.x0;
    initial.v = rec.v0;
    // diff::record's loop, with the contact solves' check after each step: strict, an
    // unconverged solve ends the run there; else it is counted and warned about.
    const auto contact_check = [&](long step, const Data& data) -> StepStatus {
      if (!model_->contact.enabled) return {};
      const StepStatus c = integrator::contact_status(*model_, data, step);
      if (c.ok() || strict_) return c;
      ++rec.contact_not_converged;
      warnings.push_back(describe(*model_, c) + " (strict=True makes it an error)");
      return {};
    };
    try {
      const StepStatus st = diff::record(*model_, *data_, initial, steps, rec.tape, actuation, contact_check);
      if (!st.ok()) return describe(*model_, st);
    } catch (const ComputationError& e) {
      return e.what();
    } catch (const std::bad_alloc&) {
      return "out of memory (an allocation failed)";
    }
    return "";
  }

  int threads_, plan_threads_ = 1;
  bool strict_, friction_ = false;
  bool busy_ = false;  // a run or sweep is under way (Busy)
  const long serial_ = ++serials_;  // unique over the process (a freed Rollout's address may be reused)
  static inline long serials_ = 0;  // (with the GIL held)
  std::unique_ptr<Model> base_, model_;  // the scene's model; the one the runs set values in
  std::unique_ptr<Data> data_;
  diff::ThetaSelection selection_;
  Eigen::Index n3_ = 0;
  long runs_ = 0;
};
// --- end torch support (ptorch) ---

// A softdiff HDF5 output (docs/output.md) read whole by the library's reader
// (io::Hdf5Reader; no h5py needed): nested dicts of float64 arrays per group (the
// XDMF views under /xdmf left out: they store no values), the root's status and
// numeric attributes. python/softdiff/__init__.py wraps it into softdiff.Result.
void read_group(const io::Hdf5Reader& reader, const std::string& path, py::dict& out) {
  for (const std::string& name : reader.members(path)) {
    const std::string child = (path == "/" ? "/" : path + "/") + name;
    if (child == "/xdmf") continue;
    std::vector<std::size_t> shape{static_cast<std::size_t>(-1)};  // untouched: not a numeric dataset
    std::vector<double> values = reader.read(child, &shape);
    if (shape.size() == 1 && shape[0] == static_cast<std::size_t>(-1)) {
      py::dict group;
      read_group(reader, child, group);
      out[py::str(name)] = group;  // a group (or a text dataset: an empty dict)
      continue;
    }
    std::vector<py::ssize_t> dims(shape.begin(), shape.end());
    py::array_t<double> a(dims);
    if (!values.empty()) std::memcpy(a.mutable_data(), values.data(), sizeof(double) * values.size());
    out[py::str(name)] = a;
  }
}

py::dict read_output(const std::string& path) {
  if (!std::filesystem::is_regular_file(path)) {
    PyErr_SetString(PyExc_FileNotFoundError, ("no such file: " + path).c_str());
    throw py::error_already_set();
  }
  py::dict out;
  std::optional<std::string> status;
  {
    py::gil_scoped_release release;
    status = io::read_status(path);
  }
  io::Hdf5Reader reader(path);
  if (!reader.ok() || !status)
    throw py::value_error(path + ": not a softdiff HDF5 output (" +
                          (reader.ok() ? std::string("no root attribute 'status'") : std::string("not an HDF5 file")) + ")");
  py::dict data;
  read_group(reader, "/", data);
  py::dict attributes;
  for (const auto& [name, value] : reader.numeric_attributes("/")) attributes[py::str(name)] = value;
  out["status"] = *status;
  out["data"] = data;
  out["attributes"] = attributes;
  return out;
}

// --- calibrate/control (pycal) ---
// softdiff.calibrate() and softdiff.control() (docs/python.md "calibrate and control"):
// the CLI's commands through the library's option handling (optim/calibrate_run.hpp,
// optim/control_run.hpp: the CLI's checks, messages and defaults), returning what the
// CLI's --json prints. python/softdiff/__init__.py turns Python values into the CLI's
// option strings (lists joined with commas, floats with repr) and refuses output=.
// The GIL is released during the run; messages are collected and issued after it
// (build warnings and the single-frame warning as SceneWarning, a solve that missed its
// tolerance as ConvergenceWarning, the target's notes in the result's "notes").

void issue_warnings(const std::vector<std::string>& messages, PyObject* category) {
  for (const auto& m : messages)
    if (PyErr_WarnEx(category, m.c_str(), 1) != 0) throw py::error_already_set();
}

// --- output files (pyout) ---
// calibrate(output=...), control(output=...) and simulate(): the CLI's file, written by
// the library's run (io/run_output.hpp, the code `softdiff simulate` runs). The run's
// messages are collected (the GIL is released) and issued after it. Ctrl-C: the
// interpreter's SIGINT handler only sets a flag; the run checks it between steps (GIL
// taken for PyErr_CheckSignals), stops after the step in progress, finishes the file as
// "interrupted" (its side files, hdf5_writer.hpp) and KeyboardInterrupt is raised naming
// where the frames are. No signal handler is installed by the module.
struct FileRunMessages {
  std::vector<std::string> warnings, scene_warnings, notes, errors;
  bool interrupted = false;
};

// The CLI's words for its options in the run's messages, as Python spells them.
std::string python_words(std::string m) {
  if (const auto at = m.find("--strict makes it an error"); at != std::string::npos) m.replace(at, 8, "strict=True");
  return m;
}

io::RunCallbacks file_run_callbacks(FileRunMessages& msg) {
  io::RunCallbacks cb;
  cb.warn = [&msg](const std::string& m) {
    // The size warning is about the output, not a solve.
    (m.rfind("the output will take", 0) == 0 ? msg.scene_warnings : msg.warnings).push_back(python_words(m));
  };
  cb.note = [&msg](const std::string& m) { msg.notes.push_back(m); };
  cb.error = [&msg](const std::string& m) { msg.errors.push_back(m); };
  cb.stop_requested = [&msg] {
    if (msg.interrupted) return true;
    py::gil_scoped_acquire acquire;
    if (PyErr_CheckSignals() != 0) {  // KeyboardInterrupt (or a Python handler's exception): raised after the run
      PyErr_Clear();
      msg.interrupted = true;
    }
    return msg.interrupted;
  };
  return cb;
}

// After a run (GIL held): its warnings, then its failure: KeyboardInterrupt for a
// Ctrl-C, StepError (exit_code 1) otherwise, the message followed by where the frames are.
void finish_file_run(const io::RunOutputResult& r, const FileRunMessages& msg) {
  issue_warnings(msg.scene_warnings, g_scene_warning);
  issue_warnings(msg.warnings, g_convergence_warning);
  if (r.ok && !msg.interrupted) return;
  std::string text = r.ok ? "interrupted as the run completed (" + r.path + " is complete)" : r.error;
  for (const auto& n : msg.notes) text += "; " + n;
  if (msg.interrupted) {
    PyErr_SetString(PyExc_KeyboardInterrupt, text.c_str());
    throw py::error_already_set();
  }
  raise(g_step_error, text, py::dict(py::arg("exit_code") = 1));
}

py::dict calibrate_py(const std::string& scene, const std::vector<std::string>& set, const std::string& param,
                      const std::string& target, const std::string& markers, const std::string& frames,
                      const std::string& init, int max_iterations, double tolerance, int threads, bool strict,
                      const std::string& output, bool force, const std::string& command) {
  if (threads < 0) throw py::value_error("threads must be >= 0 (0: all cores), got " + std::to_string(threads));
  // The CLI's checks of --max-iterations and --tolerance (its CLI11 validators, app/common.cpp:
  // the same words, the value as Python writes it).
  if (max_iterations < 1) raise(g_scene_error, "--max-iterations: must be >= 1, got " + std::to_string(max_iterations));
  if (!(tolerance > 0) || !std::isfinite(tolerance))
    raise(g_scene_error, "--tolerance: must be > 0, got " + py::repr(py::float_(tolerance)).cast<std::string>());
  optim::CalibrateRunOptions o;
  o.scene = scene;
  o.set = set;
  o.param = param;
  o.target = target;
  o.markers = markers;
  o.frames = frames;
  o.init = init;
  o.max_iterations = max_iterations;
  o.tolerance = tolerance;
  o.strict = strict;
  std::vector<std::string> warnings, notes;
  std::string input_error, run_error;
  std::optional<optim::CalibrationProblem> problem;
  optim::CalibrationResult result;
  double seconds = 0;
  std::string out_path;
  FileRunMessages file_messages;
  io::RunOutputResult file_result;
  bool ran_file = false;
  {
    py::gil_scoped_release release;
    try {
      const auto t_setup = Clock::now();
      set_threads(threads);
      problem.emplace(optim::prepare_calibration(
          o, [&](const std::string& m) { warnings.push_back(m); }, [&](const std::string& m) { notes.push_back(m); }));
      // output=: the CLI's -o (its default name is the CLI's only: None writes no file),
      // checked before the identification runs.
      if (!output.empty()) out_path = optim::calibration_output_path(o, output, force, problem->scene);
      const auto t0 = std::chrono::steady_clock::now();
      result = optim::calibrate(problem->model, problem->ids, problem->rigid_ids, problem->init, problem->target,
                                optim::calibration_options(o));
      seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (!out_path.empty()) {
        // The scene with the identified parameters, written as `calibrate -o` writes it:
        // the final run (io::OutputRun) plus /calibration.
        const Model final_model = optim::calibrated_model(*problem, result.values);
        io::RunOutputOptions ro;
        ro.scene = scene;
        ro.output = out_path;
        ro.force = force;
        ro.strict = strict;
        ro.command_line = command;
        io::RunHooks hooks;
        hooks.finish = [&](io::Hdf5Writer& w) { optim::write_calibration(w, *problem, result); };
        io::OutputRun run(ro, problem->scene, final_model, t_setup, hooks, file_run_callbacks(file_messages));
        file_result = run.run();
        ran_file = true;
      }
    } catch (const InputError& e) {
      input_error = e.what();
    } catch (const ComputationError& e) {
      run_error = e.what();
    }
  }
  issue_warnings(warnings, g_scene_warning);
  if (!input_error.empty()) raise(g_scene_error, input_error);
  if (!run_error.empty()) raise(g_step_error, run_error);
  if (ran_file) finish_file_run(file_result, file_messages);
  // The keys and order of `calibrate --json` (docs/cli.md); output: the file, or None.
  py::dict out;
  out["command"] = "calibrate";
  out["scene"] = scene;
  out["output"] = out_path.empty() ? py::object(py::none()) : py::object(py::str(out_path));
  out["converged"] = result.converged;
  out["stop_reason"] = result.stop_reason;
  out["iterations"] = result.iterations;
  out["evaluations"] = result.evaluations;
  out["rejected"] = result.rejected;
  out["failed"] = result.failed;
  out["final_cost"] = result.cost;
  out["wall_seconds"] = seconds;
  out["residuals"] = static_cast<long>(problem->target.residual_size());
  out["target_steps"] = problem->target.steps();
  out["rigid_matched"] = io::join(problem->rigid_matched);
  py::dict parameters;
  for (std::size_t k = 0; k < problem->names.size(); ++k) parameters[py::str(problem->names[k])] = result.values[k];
  out["parameters"] = parameters;
  py::list history;
  for (const auto& h : result.history) {
    py::dict d;
    d["iteration"] = h.iteration;
    d["values"] = h.values;
    d["cost"] = h.cost;
    d["gradient_norm"] = h.gradient_norm;
    d["damping"] = h.damping;
    d["seconds"] = h.seconds;
    d["evaluations"] = h.evaluations;
    d["rejected"] = h.rejected;
    d["failed"] = h.failed;
    d["last_failure"] = h.last_failure;
    history.append(d);
  }
  out["history"] = history;
  out["notes"] = notes;
  return out;
}

py::dict control_py(const std::string& scene, const std::vector<std::string>& set, const std::string& target,
                    const std::string& effector, const std::optional<long>& steps, const std::string& weights,
                    const std::string& axes, double regularization, double filter, bool shared, bool max_actuation,
                    int threads, bool strict, const std::string& output, bool overwrite, const std::string& command) {
  if (threads < 0) throw py::value_error("threads must be >= 0 (0: all cores), got " + std::to_string(threads));
  // The CLI's checks of --steps and --regularization (CLI11 validators).
  if (steps && *steps < 1) raise(g_scene_error, "--steps: must be >= 1, got " + std::to_string(*steps));
  if (!(regularization >= 0) || !std::isfinite(regularization))
    raise(g_scene_error, "--regularization: must be a non-negative number, got " +
                             py::repr(py::float_(regularization)).cast<std::string>());
  optim::ControlRunOptions o;
  o.scene = scene;
  o.set = set;
  o.target = target;
  o.effector = effector;
  o.steps = steps;
  o.weights = weights;
  o.axes = axes;
  o.regularization = regularization;
  o.filter = filter;
  o.shared = shared;
  o.max_actuation = max_actuation;
  o.strict = strict;
  std::vector<std::string> scene_warnings, run_warnings;
  std::string input_error, run_error;
  std::optional<optim::ControlProblem> problem;
  optim::ControlRunResult r;
  std::string out_path;
  FileRunMessages file_messages;
  io::RunOutputResult file_result;
  bool ran_file = false;
  {
    py::gil_scoped_release release;
    try {
      const auto t_setup = Clock::now();
      set_threads(threads);
      problem.emplace(optim::prepare_control(o, [&](const std::string& m) { scene_warnings.push_back(m); }));
      if (!output.empty()) {
        // output=: the CLI's -o, written as `control -o` writes it (io::OutputRun with
        // control's hooks); the result's series are the frames' records.
        out_path = optim::control_output_path(o, output, problem->scene);
        optim::ControlRun run(*problem, max_actuation);
        const io::RunHooks hooks = optim::control_output_hooks(*problem, run, [&](const State& st) {
          r.times.push_back(st.t);
          r.frames.push_back(run.frame());
          r.actuation.push_back(run.applied());
        });
        io::RunOutputOptions ro;
        ro.scene = scene;
        ro.output = out_path;
        ro.force = overwrite;
        ro.strict = strict;
        ro.command_line = command;
        io::OutputRun file_run(ro, problem->scene, problem->model, t_setup, hooks, file_run_callbacks(file_messages));
        file_result = file_run.run();
        ran_file = true;
        r.summary = run.summary();
        r.newton_not_converged_steps = file_result.newton_not_converged_steps;
        r.contact_not_converged_steps = file_result.contact_not_converged_steps;
        r.run_seconds = file_result.run_seconds;
      } else {
      r = optim::run_control(*problem, max_actuation, strict, [&](const std::string& m) {
        // The CLI's text, with the module's name of --strict (as Simulator's warnings).
        std::string w = m;
        if (const auto at = w.find("--strict makes it an error"); at != std::string::npos)
          w.replace(at, 8, "strict=True");
        run_warnings.push_back(w);
      });
      }
    } catch (const InputError& e) {
      input_error = e.what();
    } catch (const ComputationError& e) {
      run_error = e.what();
    }
  }
  issue_warnings(scene_warnings, g_scene_warning);
  if (!input_error.empty()) raise(g_scene_error, input_error);
  issue_warnings(run_warnings, g_convergence_warning);
  if (!run_error.empty()) raise(g_step_error, run_error);
  if (ran_file) finish_file_run(file_result, file_messages);
  const auto& s = r.summary;
  if (s.qp_not_converged_steps > 0)
    issue_warnings({std::to_string(s.qp_not_converged_steps) + " steps' QP did not converge (see the result's kkt_residual)"},
                   g_convergence_warning);
  // The keys and order of `control --json` (docs/cli.md); output: None (no file); then
  // the /control series of the CLI's file, one row per frame (output.every), frame 0 first.
  const long n = std::max<long>(1, s.steps);
  py::dict out;
  out["command"] = "control";
  out["scene"] = scene;
  out["output"] = out_path.empty() ? py::object(py::none()) : py::object(py::str(out_path));
  out["steps"] = s.steps;
  out["effector"] = s.effector;
  out["final_distance"] = s.final_distance;
  out["min_distance"] = s.min_distance;
  out["kkt_max"] = s.kkt_max;
  out["qp_not_converged_steps"] = s.qp_not_converged_steps;
  out["within_limits"] = s.within_limits;
  out["actuation_final"] = s.actuation_final;
  out["wall_seconds"] = r.run_seconds;
  out["control_ms_per_step"] = 1e3 * s.control_seconds / static_cast<double>(n);
  out["other_ms_per_step"] = 1e3 * (r.run_seconds - s.control_seconds) / static_cast<double>(n);
  const auto frames = static_cast<py::ssize_t>(r.frames.size());
  const auto na = static_cast<py::ssize_t>(problem->model.actuation.actuators.size());
  py::array_t<double> time(frames), distance(frames), kkt(frames), goal({frames, py::ssize_t{3}}),
      actuation({frames, na});
  for (py::ssize_t i = 0; i < frames; ++i) {
    const auto& f = r.frames[static_cast<std::size_t>(i)];
    time.mutable_at(i) = r.times[static_cast<std::size_t>(i)];
    distance.mutable_at(i) = f.distance;
    kkt.mutable_at(i) = f.kkt;
    for (py::ssize_t c = 0; c < 3; ++c) goal.mutable_at(i, c) = f.goal[c];
    for (py::ssize_t j = 0; j < na; ++j) actuation.mutable_at(i, j) = r.actuation[static_cast<std::size_t>(i)][j];
  }
  out["time"] = time;
  out["goal"] = goal;
  out["distance"] = distance;
  out["actuation"] = actuation;
  if (problem->model.contact.enabled) {
    py::array_t<double> force(frames);
    for (py::ssize_t i = 0; i < frames; ++i) force.mutable_at(i) = r.frames[static_cast<std::size_t>(i)].force_norm;
    out["contact_force_norm"] = force;
  }
  out["kkt_residual"] = kkt;
  out["newton_not_converged_steps"] = r.newton_not_converged_steps;
  out["contact_not_converged_steps"] = r.contact_not_converged_steps;
  return out;
}

// --- simulate (pyout) ---
// softdiff.simulate(): `softdiff simulate SCENE -o FILE` (its options; the file by
// io::OutputRun), returning the keys of `simulate --json` but "bodies" (the states are
// in the file: read_result).
py::dict simulate_py(const std::string& scene, const std::vector<std::string>& set, const std::optional<long>& steps,
                     const std::optional<double>& duration, const std::optional<double>& dt, const std::string& output,
                     bool force, const std::string& jacobian, int threads, bool strict, const std::string& command) {
  if (threads < 0) throw py::value_error("threads must be >= 0 (0: all cores), got " + std::to_string(threads));
  // The CLI's checks of --steps, --duration and --dt (its CLI11 validators, app/common.cpp).
  if (steps && duration) raise(g_scene_error, "--steps excludes --duration");
  if (steps && *steps < 1) raise(g_scene_error, "--steps: must be >= 1, got " + std::to_string(*steps));
  if (duration && !(*duration > 0 && std::isfinite(*duration)))
    raise(g_scene_error, "--duration: must be > 0 s, got " + py::repr(py::float_(*duration)).cast<std::string>());
  if (dt && !(*dt > 0 && std::isfinite(*dt)))
    raise(g_scene_error, "--dt: must be > 0 s, got " + py::repr(py::float_(*dt)).cast<std::string>());
  std::vector<std::string> build_warnings;
  std::string input_error, run_error;
  FileRunMessages messages;
  io::RunOutputResult r;
  std::optional<io::SceneDesc> desc;
  std::optional<Model> model;
  {
    py::gil_scoped_release release;
    try {
      const auto t_setup = Clock::now();
      set_threads(threads);
      desc.emplace(io::load_scene(scene, io::simulate_overrides(set, steps, duration, dt)));
      io::BuildReport report;
      report.strict = strict;
      model.emplace(io::build_model(*desc, &report));
      build_warnings = report.warnings;
      io::RunOutputOptions ro;
      ro.scene = scene;
      ro.output = output;
      ro.force = force;
      ro.jacobian = jacobian;
      ro.strict = strict;
      ro.command_line = command;
      io::OutputRun run(ro, *desc, *model, t_setup, {}, file_run_callbacks(messages));
      r = run.run();
    } catch (const InputError& e) {
      input_error = e.what();
    } catch (const ComputationError& e) {
      run_error = e.what();
    }
  }
  issue_warnings(build_warnings, g_scene_warning);
  if (!input_error.empty()) raise(g_scene_error, input_error);
  if (!run_error.empty()) raise(g_step_error, run_error, py::dict(py::arg("exit_code") = 1));
  finish_file_run(r, messages);
  const double n = static_cast<double>(std::max<long>(1, r.steps_done));
  py::dict out;
  out["command"] = "simulate";
  out["scene"] = scene;
  out["output"] = r.path;
  out["status"] = r.status;
  out["steps"] = r.steps_done;
  out["frames"] = r.frames;
  out["time"] = r.state.t;
  out["wall_seconds"] = r.run_seconds;
  out["setup_seconds"] = r.setup_seconds;
  py::dict ms;
  ms["assembly"] = 1e3 * r.timings.assembly / n;
  ms["factorization"] = 1e3 * r.timings.factorization / n;
  ms["solve"] = 1e3 * r.timings.solve / n;
  ms["other"] = 1e3 * r.timings.other / n;
  ms["contact"] = 1e3 * r.timings.contact() / n;
  ms["detection"] = 1e3 * r.timings.detection / n;
  ms["delassus"] = 1e3 * r.timings.delassus / n;
  ms["ncp"] = 1e3 * r.timings.ncp / n;
  ms["correction"] = 1e3 * r.timings.correction / n;
  ms["derivatives"] = 1e3 * r.derivative_seconds / n;
  ms["output"] = 1e3 * r.output_seconds / n;
  out["ms_per_step"] = ms;
  out["factorizations"] = r.factorizations;
  py::dict ls;
  ls["numeric_factorizations"] = r.solver.numeric_factorizations;
  ls["kept_factors"] = r.solver.kept_factors;
  ls["pcg_solves"] = r.solver.pcg_solves;
  ls["pcg_iterations"] = r.solver.pcg_iterations;
  ls["pcg_fallbacks"] = r.solver.pcg_fallbacks;
  out["linear_solver"] = ls;
  if (r.jacobian) {
    py::dict d;
    d["ncp_rank_deficient_steps"] = r.rank_deficient_steps;
    d["ncp_rank_deficiency_max"] = r.rank_deficiency_max;
    d["nondifferentiable_contacts"] = r.nondifferentiable_contacts;
    d["smoothed_contacts"] = r.smoothed_contacts;
    out["derivatives"] = d;
  }
  out["newton_not_converged_steps"] = r.newton_not_converged_steps;
  if (model->contact.enabled) {
    py::dict c;
    c["contacts_mean"] = static_cast<double>(r.contacts_total) / n;
    c["contacts_max"] = r.contacts_max;
    c["iterations_mean"] = static_cast<double>(r.contact_iterations) / n;
    c["not_converged_steps"] = r.contact_not_converged_steps;
    out["contact"] = c;
  }
  return out;
}
// --- end simulate (pyout) ---

void bind_calibrate_control(py::module_& m) {
  m.def("_calibrate", &calibrate_py, py::arg("scene"), py::arg("set"), py::arg("param"), py::arg("target"),
        py::arg("markers"), py::arg("frames"), py::arg("init"), py::arg("max_iterations"), py::arg("tolerance"),
        py::arg("threads"), py::arg("strict"), py::arg("output"), py::arg("force"), py::arg("command"));
  m.def("_control", &control_py, py::arg("scene"), py::arg("set"), py::arg("target"), py::arg("effector"),
        py::arg("steps"), py::arg("weights"), py::arg("axes"), py::arg("regularization"), py::arg("filter"),
        py::arg("shared_actuation"), py::arg("max_actuation"), py::arg("threads"), py::arg("strict"), py::arg("output"),
        py::arg("force"), py::arg("command"));
  m.def("_simulate", &simulate_py, py::arg("scene"), py::arg("set"), py::arg("steps"), py::arg("duration"),
        py::arg("dt"), py::arg("output"), py::arg("force"), py::arg("jacobian"), py::arg("threads"), py::arg("strict"),
        py::arg("command"));  // simulate (pyout)
}
// --- end calibrate/control (pycal) ---


}  // namespace
}  // namespace softdiff::python

PYBIND11_MODULE(_softdiff, m) {
  using namespace softdiff::python;
  m.doc() = "softdiff: differentiable soft-robot simulation (docs/python.md)";
  m.attr("__version__") = SOFTDIFF_VERSION;

  // SceneError is a ValueError, StepError a RuntimeError, ConvergenceWarning a
  // RuntimeWarning: code that catches the builtin kinds still catches them.
  static py::exception<softdiff::InputError> scene_error(m, "SceneError", PyExc_ValueError);
  static py::exception<softdiff::ComputationError> step_error(m, "StepError", PyExc_RuntimeError);
  g_scene_error = scene_error.ptr();
  g_step_error = step_error.ptr();
  scene_error.attr("exit_code") = 2;
  step_error.attr("exit_code") = 1;
  scene_error.attr("__module__") = "softdiff";  // shown as softdiff.SceneError in tracebacks
  step_error.attr("__module__") = "softdiff";
  g_convergence_warning = PyErr_NewException("softdiff.ConvergenceWarning", PyExc_RuntimeWarning, nullptr);
  m.attr("ConvergenceWarning") = py::reinterpret_steal<py::object>(g_convergence_warning);
  // The build's plausibility warnings (a body of implausible size or mass; strict: SceneError).
  g_scene_warning = PyErr_NewException("softdiff.SceneWarning", PyExc_UserWarning, nullptr);
  m.attr("SceneWarning") = py::reinterpret_steal<py::object>(g_scene_warning);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const softdiff::InputError& e) {
      PyErr_SetString(g_scene_error, e.what());
    } catch (const softdiff::ComputationError& e) {
      PyErr_SetString(g_step_error, e.what());
    }
  });

  py::class_<Scene>(m, "Scene", "A scene file loaded and validated (softdiff.load_scene)")
      .def_property_readonly("path", [](const Scene& s) { return s.path; })
      .def_property_readonly("overrides", [](const Scene& s) { return s.overrides; })
      .def_property_readonly("name", [](const Scene& s) { return s.desc.name; })
      .def_property_readonly("text", [](const Scene& s) { return s.desc.text; })
      .def("__repr__", [](const Scene& s) { return "<softdiff.Scene '" + s.desc.name + "' from " + s.path + ">"; });

  m.def("_load_scene", &load_scene, py::arg("path"), py::arg("overrides"));
  m.def("_read_output", &read_output, py::arg("path"));
  bind_calibrate_control(m);  // calibrate/control (pycal)

  py::class_<Simulator>(m, "Simulator")
      .def(py::init([](const Scene& scene, int threads, bool strict, const py::object& jacobian) {
             // jacobian: None, "young, x0", or a list of names (joined as the CLI's list).
             std::optional<std::string> list;
             if (py::isinstance<py::str>(jacobian)) {
               list = jacobian.cast<std::string>();
             } else if (!jacobian.is_none()) {
               list.emplace();
               for (const auto& name : jacobian) {
                 if (!py::isinstance<py::str>(name)) throw py::type_error("jacobian: names as strings, e.g. ['young', 'x0']");
                 *list += (list->empty() ? "" : ",") + name.cast<std::string>();
               }
             }
             return std::make_unique<Simulator>(scene, threads, strict, list);
           }),
           py::arg("scene"), py::arg("threads") = 1, py::arg("strict") = false, py::arg("jacobian") = py::none(),
           "Build the scene's model and workspace. threads: softdiff's OpenMP loops and OpenBLAS (0: all cores, "
           "as the CLI's default); strict: as the CLI's --strict; jacobian: theta groups as the CLI's --jacobian "
           "(comma-separated), carried by forward sensitivities through every step.")
      .def("step", &Simulator::step, "One time step (the GIL is released); raises StepError")
      .def("run", &Simulator::run, py::arg("steps") = py::none(),
           "steps time steps: dict body -> numpy (steps + 1, n, 3) positions, frame 0 the current state "
           "(rigid bodies: (steps + 1, 7) position + quaternion w, x, y, z)")
      .def("x", &Simulator::x, py::arg("body"), "Positions now: soft (n, 3); rigid (7,) position + quaternion w, x, y, z")
      .def("v", &Simulator::v, py::arg("body"), "Velocities now: soft (n, 3); rigid (6,) velocity + angular velocity")
      .def("jacobian", &Simulator::jacobian, py::arg("of") = "x",
           "d x / d theta (of='v': d v / d theta) at the current state: dict theta group -> (rows, k) array")
      .def_property_readonly("theta_columns", &Simulator::theta_columns, "dict theta group -> its column names")
      // --- pyrig ---
      .def("step_jvp", &Simulator::step_jvp, py::arg("dx") = py::none(), py::arg("dv") = py::none(),
           py::arg("dtheta") = py::dict(), py::arg("dx_prev") = py::none(), py::arg("dv_prev") = py::none(),
           "The last step's JVP: (dx_out, dv_out) for tangents dx, dv of its input state (jacobian()'s rows: 3n soft, "
           "then 6 per rigid body), dx_prev, dv_prev of the frame before it (BDF2) and dtheta (theta group -> values)")
      .def("step_vjp", &Simulator::step_vjp, py::arg("bar_x") = py::none(), py::arg("bar_v") = py::none(),
           "The last step's VJP: dict x, v (its input state), x_prev, v_prev (the frame before it, BDF2) and theta "
           "groups, for cotangents bar_x, bar_v of its output state (jacobian()'s rows)")
      // --- end pyrig ---
      .def("adjoint", &Simulator::adjoint, py::arg("steps") = py::none(), py::arg("bar_x") = py::none(),
           py::arg("bar_v") = py::none(), py::arg("bar_rigid") = py::none(), py::arg("theta") = py::none(),
           "Gradient of l = bar_x . x_T + bar_v . v_T (T = steps from now) by the adjoint: dict theta group -> "
           "dl/dtheta, x, v, rigid (of the current state), x_T, v_T; the simulator's state is unchanged")
      .def("rows", &Simulator::rows, py::arg("body"), "The slice of a body's rows in jacobian()'s arrays")
      // --- pyrig ---
      .def("set_x", [](Simulator& s, const std::string& body, const py::object& a) { s.set_state(body, a, false); },
           py::arg("body"), py::arg("values"),
           "Set a body's positions (soft (n, 3); free rigid (7,) position + unit quaternion w, x, y, z): a restart "
           "from that state (docs/python.md)")
      .def("set_v", [](Simulator& s, const std::string& body, const py::object& a) { s.set_state(body, a, true); },
           py::arg("body"), py::arg("values"),
           "Set a body's velocities (soft (n, 3); free rigid (6,) velocity + angular velocity): a restart")
      .def("advance", &Simulator::advance_steps, py::arg("steps"),
           "steps time steps in C++ without frames (the GIL released once); raises StepError")
      .def_property("time", &Simulator::time, &Simulator::set_time, "the state's time (settable: a restart)")
      // --- end pyrig ---
      .def_property_readonly("steps_done", &Simulator::steps_done)
      .def_property_readonly("dt", &Simulator::dt)
      .def_property_readonly("scene_steps", &Simulator::scene_steps, "the scene's simulation.steps (or duration / dt)")
      .def_property_readonly("threads", &Simulator::threads)
      .def_property_readonly("bodies", &Simulator::bodies, "body names: soft bodies, then rigid bodies")
      .def_property_readonly("newton_not_converged_steps", &Simulator::newton_not_converged)
      .def_property_readonly("contact_not_converged_steps", &Simulator::contact_not_converged);

  // --- torch support (ptorch) ---
  py::class_<Recording, std::shared_ptr<Recording>>(m, "Recording",
                                                    "A recorded run of Rollout.record() (its states, actuation values "
                                                    "and contact warm starts), for Rollout.adjoint()")
      .def_property_readonly("steps", [](const Recording& r) { return r.tape.steps(); })
      .def_property_readonly("bytes", [](const Recording& r) { return r.tape.bytes(); })
      .def_property_readonly("id", [](const Recording& r) { return r.id; })
      .def_property_readonly("contact_not_converged_steps", [](const Recording& r) { return r.contact_not_converged; })
      .def_property_readonly("values", [](const Recording& r) { return std::vector<double>(r.values.data(), r.values.data() + r.values.size()); });
  py::class_<Rollout>(m, "Rollout")
      .def(py::init<const Scene&, const py::object&, int, bool>(), py::arg("scene"), py::arg("theta") = py::none(),
           py::arg("threads") = 1, py::arg("strict") = false,
           "A scene's model for differentiated runs (softdiff.torch): theta = material parameter groups "
           "(young, poisson, density, rayleigh_mass, rayleigh_stiffness, friction)")
      .def("record", &Rollout::record, py::arg("steps"), py::arg("values") = py::none(), py::arg("actuation") = py::none(),
           py::arg("x0") = py::none(), py::arg("v0") = py::none(),
           "Run steps steps with theta's values and the actuation sequence (steps, n_actuators): (x, v, recording), "
           "x, v (steps + 1, n, 3)")
      .def("adjoint", &Rollout::adjoint, py::arg("recording"), py::arg("bar_x") = py::none(), py::arg("bar_v") = py::none(),
           "Reverse sweep over a recording for l = sum_k bar_x[k] . x_k + bar_v[k] . v_k: dict theta, actuation, x0, v0, "
           "recompute_mismatch")
      .def("schedule", &Rollout::schedule, py::arg("steps"), "The actuators' scheduled values of steps 1..steps, (steps, n_a)")
      .def("effector", &Rollout::effector, py::arg("name"), "(node indices, weights) of an effector")
      .def("nodes", &Rollout::nodes, py::arg("body"), "A soft body's slice of the node axis")
      .def_property_readonly("theta_values", &Rollout::theta_values, "the scene's values of theta's columns")
      .def_property_readonly("theta_columns", &Rollout::theta_columns)
      .def_property_readonly("theta_groups", &Rollout::theta_groups)
      .def_property_readonly("actuators", &Rollout::actuators)
      .def_property_readonly("num_actuators", &Rollout::num_actuators)
      .def_property_readonly("num_nodes", &Rollout::num_nodes)
      .def_property_readonly("dt", &Rollout::dt);
  // --- end torch support (ptorch) ---

  m.def(
      "thread_plan",
      [] {
        const softdiff::ThreadPlan p = softdiff::thread_plan();
        py::dict d;
        d["threads"] = p.threads;
        d["blas_threads"] = p.blas_threads;
        d["openblas"] = p.openblas;
        d["blas"] = p.blas;
        return d;
      },
      "The thread plan in force and the BLAS loaded (docs/python.md \"BLAS\")");
}
