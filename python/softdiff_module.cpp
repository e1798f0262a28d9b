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
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>
#include <softdiff/version.hpp>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cstring>
#include <memory>
#include <new>
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
  Simulator(const Scene& scene, int threads, bool strict) : threads_(threads), strict_(strict) {
    if (threads < 0) throw py::value_error("threads must be >= 0 (0: all cores), got " + std::to_string(threads));
    io::BuildReport report;
    report.strict = strict;
    try {
      py::gil_scoped_release release;
      set_threads(threads_);
      model_ = std::make_unique<Model>(io::build_model(scene.desc, &report));
    } catch (const InputError& e) {
      raise(g_scene_error, e.what());
    } catch (const ComputationError& e) {
      raise(g_step_error, e.what());
    }
    for (const auto& w : report.warnings) warn(w, g_scene_warning);
    if (model_->step.integrator == IntegratorKind::static_equilibrium)
      throw py::value_error(
          "static scenes (simulation.integrator: static) are not bound in Python yet (issue 23): run them with "
          "`softdiff simulate`");
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

  // One step; raises StepError (the state is left at the last completed step).
  void step() {
    std::string warning, failure;
    {
      py::gil_scoped_release release;
      failure = advance(warning);
    }
    finish_step(warning, failure, nullptr);
  }

  // `steps` steps: body name -> (steps + 1, n, 3) positions (rigid: (steps + 1, 7)),
  // frame 0 the state before the first step.
  py::dict run(long steps) {
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
  void write_frame(const std::vector<double*>& buffers, long i) const {
    std::size_t j = 0;
    for (const auto& body : model_->fem.bodies) {
      const std::size_t count = 3 * static_cast<std::size_t>(body.num_nodes);
      std::memcpy(buffers[j++] + static_cast<std::size_t>(i) * count, state_.x.data() + 3L * body.node_begin,
                  sizeof(double) * count);
    }
    for (const auto& rs : state_.rigid) pose(rs, buffers[j++] + 7 * i);
  }

  // The step of cmd_simulate.cpp's loop, without the GIL: "" or the failure's message;
  // `warning`: a non-convergence warning to issue (non-strict).
  std::string advance(std::string& warning) {
    if (thread_plan().threads != threads_ && !(threads_ == 0)) set_threads(threads_);
    const long k = k_ + 1;
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
      const auto& cd = data_->contact;
      if (!cd.result.converged) {
        StepStatus c;
        c.code = StepStatus::Code::contact_not_converged;
        c.step = k;
        std::ostringstream d;
        d.precision(3);
        d << (model_->contact.ncp.solver == contact::NcpSolverKind::admm ? "ADMM" : "PGS") << ", "
          << cd.contacts.size() << " contacts, " << cd.result.iterations << " iterations: residuals primal "
          << cd.result.residuals.primal << ", dual " << cd.result.residuals.dual << ", complementarity "
          << cd.result.residuals.complementarity << " > tolerance " << model_->contact.ncp.tolerance;
        c.detail = d.str();
        if (strict_) return describe(*model_, c);
        ++contact_not_converged_;
        warning = describe(*model_, c) + " (strict=True makes it an error)";
      }
    }
    std::swap(previous_, state_);  // BDF2's history
    std::swap(state_, next_);
    k_ = k;
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
  bool strict_;
  std::unique_ptr<Model> model_;  // a fixed address: Data and the step refer to it
  std::unique_ptr<Data> data_;
  State state_, next_, previous_;
  long k_ = 0;  // steps done
  long newton_not_converged_ = 0, contact_not_converged_ = 0;
  std::vector<std::string> names_;  // soft bodies, then rigid bodies (run()'s order)
};

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

  py::class_<Simulator>(m, "Simulator")
      .def(py::init<const Scene&, int, bool>(), py::arg("scene"), py::arg("threads") = 1, py::arg("strict") = false,
           "Build the scene's model and workspace. threads: softdiff's OpenMP loops and OpenBLAS (0: all cores, "
           "as the CLI's default); strict: as the CLI's --strict.")
      .def("step", &Simulator::step, "One time step (the GIL is released); raises StepError")
      .def("run", &Simulator::run, py::arg("steps"),
           "steps time steps: dict body -> numpy (steps + 1, n, 3) positions, frame 0 the current state "
           "(rigid bodies: (steps + 1, 7) position + quaternion w, x, y, z)")
      .def("x", &Simulator::x, py::arg("body"), "Positions now: soft (n, 3); rigid (7,) position + quaternion w, x, y, z")
      .def("v", &Simulator::v, py::arg("body"), "Velocities now: soft (n, 3); rigid (6,) velocity + angular velocity")
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
