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
#include <softdiff/diff/theta_selection.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/integrator/bdf2.hpp>
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
  // The last step's JVP (integrator::StepDerivatives::jvp): tangents of its input state
  // (dx, dv: 3n each, soft nodes) and of theta's groups (dtheta: group -> its size; not
  // x0, v0: those are dx, dv) -> (dx_out, dv_out). Implicit Euler scenes of soft bodies
  // (the step's derivative with rigid bodies or BDF2 chains more: issue 23).
  py::tuple step_jvp(const py::object& dx, const py::object& dv, const py::dict& dtheta) {
    demand_step_derivative();
    integrator::StepTangent d;
    const Eigen::Index n3 = state_.x.size();
    d.x = vector_or_zero(dx, n3, "dx");
    d.v = vector_or_zero(dv, n3, "dv");
    d.p = VecX::Zero(static_cast<Eigen::Index>(theta_->layout.parameters.size()));
    d.lambda_a = VecX::Zero(static_cast<Eigen::Index>(model_->actuation.actuators.size()));
    for (auto item : dtheta) {
      const std::string name = py::str(item.first);
      const diff::ThetaGroup& g = group(name);
      const VecX value = vector_or_zero(py::reinterpret_borrow<py::object>(item.second), g.size, "dtheta['" + name + "']");
      if (name == "actuation")
        d.lambda_a = value;
      else
        d.p.segment(g.offset, g.size) = value;
    }
    integrator::StateTangent out;
    bool ok = false;
    {
      py::gil_scoped_release release;
      ok = step_derivatives_->jvp(*model_, *data_, previous_, state_, d, out);
    }
    if (!ok) raise(g_step_error, "the derivative of step " + std::to_string(k_) + " failed (a linear solve did not "
                                 "succeed or gave non-finite values)");
    return py::make_tuple(to_numpy(out.x, n3), to_numpy(out.v, n3));
  }

  // The last step's VJP: cotangents of its output state (bar_x, bar_v) -> dict "x", "v"
  // (of its input state) and one entry per theta group but x0, v0.
  py::dict step_vjp(const py::object& bar_x, const py::object& bar_v) {
    demand_step_derivative();
    const Eigen::Index n3 = state_.x.size();
    integrator::StateTangent bar;
    bar.x = vector_or_zero(bar_x, n3, "bar_x");
    bar.v = vector_or_zero(bar_v, n3, "bar_v");
    integrator::StepCotangent in;
    bool ok = false;
    {
      py::gil_scoped_release release;
      ok = step_derivatives_->vjp(*model_, *data_, previous_, state_, bar, in);
    }
    if (!ok) raise(g_step_error, "the derivative of step " + std::to_string(k_) + " failed (a linear solve did not "
                                 "succeed or gave non-finite values)");
    py::dict out;
    out["x"] = to_numpy(in.x, n3);
    out["v"] = to_numpy(in.v, n3);
    for (const auto& g : theta_->groups) {
      if (g.name == "x0" || g.name == "v0") continue;
      if (g.name == "actuation")
        out[py::str(g.name)] = to_numpy(in.lambda_a, g.size);
      else
        out[py::str(g.name)] = to_numpy(in.p.size() ? VecX(in.p.segment(g.offset, g.size)) : VecX(), g.size);
    }
    return out;
  }

  // The gradient of a loss of the state `steps` steps from now, l = bar_x . x_T +
  // bar_v . v_T (+ bar_rigid . the rigid states' tangent), by the adjoint (diff::record,
  // diff::adjoint): a run of its own from the current state on a workspace of its own
  // (the simulator's state and record are unchanged), the reverse sweep recomputing it.
  // theta: groups as jacobian= (default: the simulator's).
  py::dict adjoint(long steps, const py::object& bar_x, const py::object& bar_v, const py::object& bar_rigid,
                   const py::object& theta) {
    if (is_static_)
      throw py::value_error("adjoint() of a static scene is not bound yet (issue 23): jacobian() after run() gives "
                            "d x* / d theta");
    if (steps < 0) throw py::value_error("steps must be >= 0, got " + std::to_string(steps));
    diff::ThetaSelection selection;
    if (!theta.is_none()) {
      try {
        selection = diff::parse_theta("theta", theta_list(theta), *model_);
      } catch (const InputError& e) {
        raise(g_scene_error, e.what());
      }
    } else if (theta_) {
      selection = *theta_;
    } else {
      throw py::value_error("no theta: give adjoint(..., theta=\"young, ...\") or Simulator(scene, jacobian=...)");
    }
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
    if (thread_plan().threads != plan_threads_) set_threads(threads_);
  }
  void demand_step_derivative() {
    if (!theta_) throw py::value_error("no theta: give Simulator(scene, jacobian=\"young, ...\") first");
    if (is_static_)
      throw py::value_error("step_jvp/step_vjp: a static scene has no time step; jacobian() after run() gives d x* / d theta");
    if (!model_->rigid.empty())
      throw py::value_error("step_jvp/step_vjp with rigid bodies are not bound yet (issue 23): use jacobian() (forward "
                            "sensitivities through the steps)");
    if (model_->step.integrator != IntegratorKind::implicit_euler)
      throw py::value_error("step_jvp/step_vjp are bound for implicit_euler only (issue 23: BDF2's step depends on two "
                            "states): use jacobian()");
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
      s = integrator::time_step(*model_, *data_, state_, k > 1 ? &previous_ : nullptr, next_, k);
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

py::dict calibrate_py(const std::string& scene, const std::vector<std::string>& set, const std::string& param,
                      const std::string& target, const std::string& markers, const std::string& frames,
                      const std::string& init, int max_iterations, double tolerance, int threads, bool strict) {
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
  {
    py::gil_scoped_release release;
    try {
      set_threads(threads);
      problem.emplace(optim::prepare_calibration(
          o, [&](const std::string& m) { warnings.push_back(m); }, [&](const std::string& m) { notes.push_back(m); }));
      const auto t0 = std::chrono::steady_clock::now();
      result = optim::calibrate(problem->model, problem->ids, problem->rigid_ids, problem->init, problem->target,
                                optim::calibration_options(o));
      seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    } catch (const InputError& e) {
      input_error = e.what();
    } catch (const ComputationError& e) {
      run_error = e.what();
    }
  }
  issue_warnings(warnings, g_scene_warning);
  if (!input_error.empty()) raise(g_scene_error, input_error);
  if (!run_error.empty()) raise(g_step_error, run_error);
  // The keys and order of `calibrate --json` (docs/cli.md); output: None (no file).
  py::dict out;
  out["command"] = "calibrate";
  out["scene"] = scene;
  out["output"] = py::none();
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
                    int threads, bool strict) {
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
  {
    py::gil_scoped_release release;
    try {
      set_threads(threads);
      problem.emplace(optim::prepare_control(o, [&](const std::string& m) { scene_warnings.push_back(m); }));
      r = optim::run_control(*problem, max_actuation, strict, [&](const std::string& m) {
        // The CLI's text, with the module's name of --strict (as Simulator's warnings).
        std::string w = m;
        if (const auto at = w.find("--strict makes it an error"); at != std::string::npos)
          w.replace(at, 8, "strict=True");
        run_warnings.push_back(w);
      });
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
  out["output"] = py::none();
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

void bind_calibrate_control(py::module_& m) {
  m.def("_calibrate", &calibrate_py, py::arg("scene"), py::arg("set"), py::arg("param"), py::arg("target"),
        py::arg("markers"), py::arg("frames"), py::arg("init"), py::arg("max_iterations"), py::arg("tolerance"),
        py::arg("threads"), py::arg("strict"));
  m.def("_control", &control_py, py::arg("scene"), py::arg("set"), py::arg("target"), py::arg("effector"),
        py::arg("steps"), py::arg("weights"), py::arg("axes"), py::arg("regularization"), py::arg("filter"),
        py::arg("shared_actuation"), py::arg("max_actuation"), py::arg("threads"), py::arg("strict"));
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
      .def("step_jvp", &Simulator::step_jvp, py::arg("dx") = py::none(), py::arg("dv") = py::none(),
           py::arg("dtheta") = py::dict(),
           "The last step's JVP: (dx_out, dv_out) for tangents dx, dv of its input state and dtheta "
           "(theta group -> values); implicit Euler, soft bodies")
      .def("step_vjp", &Simulator::step_vjp, py::arg("bar_x") = py::none(), py::arg("bar_v") = py::none(),
           "The last step's VJP: dict x, v (input state) and theta groups, for cotangents of its output state")
      .def("adjoint", &Simulator::adjoint, py::arg("steps"), py::arg("bar_x") = py::none(),
           py::arg("bar_v") = py::none(), py::arg("bar_rigid") = py::none(), py::arg("theta") = py::none(),
           "Gradient of l = bar_x . x_T + bar_v . v_T (T = steps from now) by the adjoint: dict theta group -> "
           "dl/dtheta, x, v, rigid (of the current state), x_T, v_T; the simulator's state is unchanged")
      .def("rows", &Simulator::rows, py::arg("body"), "The slice of a body's rows in jacobian()'s arrays")
      .def_property_readonly("time", &Simulator::time)
      .def_property_readonly("steps_done", &Simulator::steps_done)
      .def_property_readonly("dt", &Simulator::dt)
      .def_property_readonly("scene_steps", &Simulator::scene_steps, "the scene's simulation.steps (or duration / dt)")
      .def_property_readonly("threads", &Simulator::threads)
      .def_property_readonly("bodies", &Simulator::bodies, "body names: soft bodies, then rigid bodies")
      .def_property_readonly("newton_not_converged_steps", &Simulator::newton_not_converged)
      .def_property_readonly("contact_not_converged_steps", &Simulator::contact_not_converged);

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
