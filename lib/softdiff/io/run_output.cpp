// The run that writes a softdiff output file: see run_output.hpp. Moved from app/cmd_simulate.cpp
// (simulate_model) on 2026-12-04, branch pyout.
#include <algorithm>
#include <atomic>
#include <cctype>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <new>
#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/diff/theta_selection.hpp>
#include <softdiff/integrator/bdf2.hpp>
#include <softdiff/integrator/contact_status.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <softdiff/integrator/static_solver_derivatives.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/run_output.hpp>
#include <softdiff/io/units.hpp>
#include <sstream>

namespace softdiff::io {
namespace {

using Sink = std::function<void(const std::string&)>;
void say(const Sink& sink, const std::string& message) {
  if (sink) sink(message);
}
using diff::parse_theta;
using diff::ThetaGroup;
using diff::ThetaSelection;

// Above this estimate a run warns before it starts (docs/cli.md).
constexpr double kLargeOutputBytes = 10e9;

std::string fmt_bytes(double bytes) {
  char buf[32];
  const char* unit = "B";
  for (const char* u : {"kB", "MB", "GB", "TB"}) {
    if (bytes < 1000) break;
    bytes /= 1000;
    unit = u;
  }
  std::snprintf(buf, sizeof buf, "%.3g %s", bytes, unit);
  return buf;
}

// Exit 2 when the estimated output cannot fit in its folder's free space; a warning above
// kLargeOutputBytes.
void check_output_space(const std::filesystem::path& out, const io::OutputEstimate& e, long frames, const Sink& warn) {
  namespace fs = std::filesystem;
  const fs::path folder = out.parent_path().empty() ? fs::path(".") : out.parent_path();
  std::ostringstream what;
  what << "the output will take about " << fmt_bytes(e.total()) << " (" << frames << " frames x "
       << fmt_bytes(e.frame_bytes) << " in HDF5, plus " << fmt_bytes(e.xdmf_bytes) << " of XDMF)";
  std::error_code ec;
  const fs::space_info space = fs::space(folder, ec);
  if (!ec && e.total() > static_cast<double>(space.available))
    throw InputError(out.string() + ": " + what.str() + " but " + folder.string() + " has " +
                     fmt_bytes(static_cast<double>(space.available)) +
                     " free; use fewer steps (--steps, --duration), a larger "
                     "output.every, or another folder (-o)");
  if (e.total() > kLargeOutputBytes && warn) warn(what.str());
}

// A run stopped by its first signal in a static solve (the solver has no stop test between load
// steps: the frame callback throws this).
struct StopRequested {};

// The units of /jacobians/<group>: d x (m) / d theta, per column when they differ.
std::string jacobian_units(const Model& model, const ThetaGroup& g) {
  if (g.name == "x0") return "1";
  if (g.name == "v0") return "s";
  // Rigid parameters (issue 21): per kg, per kg m^2 (a rigid body's rotation rows: rad per the
  // same, docs/output.md).
  if (g.name == "mass") return "m/kg";
  if (g.name == "inertia") return "1/(kg m)";
  if (g.name == "actuation") {
    std::vector<std::string> units;
    for (const auto& a : model.actuation.actuators) units.push_back(position_per(actuator_value_unit(a)));
    return column_units(units);
  }
  const std::optional<Parameter> p = parse_parameter(g.name);
  SOFTDIFF_DEMAND(p.has_value(), "no unit for theta '" + g.name + "'");
  return position_per(parameter_unit(*p));
}

}  // namespace

std::vector<std::string> simulate_overrides(const std::vector<std::string>& set, std::optional<long> steps,
                                            std::optional<double> duration, std::optional<double> dt) {
  std::vector<std::string> overrides = set;
  if (dt) overrides.push_back("simulation.dt=" + std::to_string(*dt));
  if (steps) overrides.push_back("simulation.steps=" + std::to_string(*steps));
  if (duration) {
    std::ostringstream s;
    s.precision(17);
    s << "simulation.duration=" << *duration;
    overrides.push_back(s.str());
  }
  return overrides;
}

std::vector<std::string> scene_input_files(const SceneDesc& scene) {
  std::vector<std::string> files{scene.file.string()};
  for (const auto& b : scene.bodies) files.push_back(b.mesh.string());
  for (const auto& r : scene.rigid_bodies)
    if (!r.shape.mesh.empty()) files.push_back(r.shape.mesh.string());
  for (const auto& o : scene.obstacles)
    if (!o.mesh.empty()) files.push_back(o.mesh.string());
  return files;
}

void check_output_is_not_input(const std::string& output, const std::vector<std::string>& inputs) {
  namespace fs = std::filesystem;
  for (const fs::path& written : output_file_names(output)) {
    for (const auto& input : inputs) {
      if (input.empty()) continue;
      std::error_code ec;
      // equivalent(): the same file (device and inode), whatever the spelling.
      if (fs::equivalent(written, input, ec) && !ec)
        throw InputError(output + ": the output would overwrite the input file " + input +
                         (written == fs::path(output) ? std::string() : " (as " + written.string() + ")") +
                         "; choose another -o");
    }
  }
}

struct OutputRun::Impl {
  RunOutputOptions o;
  const SceneDesc& scene;
  const Model& model;
  RunHooks hooks;
  RunCallbacks cb;
  std::optional<Data> own_data;
  Data* data_ptr = nullptr;
  // A caller's actuation (control): the values each step used, for the series.
  VecX applied;
  bool applied_set = false;
  std::optional<ThetaSelection> theta;
  std::unique_ptr<diff::ForwardSensitivity> sensitivity;
  double setup_seconds = 0;
  std::filesystem::path out_path;
  WriterOptions wo;
  std::vector<OutputBody> out_bodies;
  bool is_static = false;
  long total = 0, every = 1;
  bool ran = false;

  // The second signal (abandon) may finish the file from another thread while a step computes:
  // writer_mutex keeps that from meeting a frame being written: every use of the writer in run()
  // holds it.
  std::mutex writer_mutex;
  std::unique_ptr<Hdf5Writer> writer_ptr;  // created under writer_mutex
  bool writer_done = false;                // under writer_mutex: finish() was called
  std::atomic<long> step_in_progress{0};   // 0 between steps

  Impl(const RunOutputOptions& options, const SceneDesc& scene_, const Model& model_, Clock::time_point t_setup,
       RunHooks hooks_, RunCallbacks callbacks)
      : o(options), scene(scene_), model(model_), hooks(std::move(hooks_)), cb(std::move(callbacks)) {
    if (!hooks.data) own_data.emplace(model);
    data_ptr = hooks.data ? hooks.data : &*own_data;
    // A caller's actuation (control): the values each step used, for the series.
    applied = VecX::Zero(static_cast<Eigen::Index>(model.actuation.actuators.size()));
    if (!o.jacobian.empty()) {
      theta = parse_theta("--jacobian", o.jacobian, model);
      sensitivity = std::make_unique<diff::ForwardSensitivity>(model, theta->layout);
    }
    setup_seconds = seconds_since(t_setup);

    out_path = o.output;
    if (out_path.empty()) out_path = scene.output.file;
    if (out_path.empty()) out_path = std::filesystem::path(o.scene).stem().string() + ".h5";
    check_output_is_not_input(out_path.string(), scene_input_files(scene));

    wo.file = out_path;
    wo.force = o.force;
    wo.write_v = scene.output.v;
    wo.write_contact_force = model.contact.enabled;
    wo.gzip_level = scene.output.gzip_level;
    wo.command = o.command_line;
    wo.scene_yaml = scene.text;
    for (const auto& b : model.fem.bodies) {
      if (b.mesh.order == 2)
        out_bodies.push_back({b.name, b.mesh.X, b.mesh.tets10, b.surface6});
      else
        out_bodies.push_back({b.name, b.mesh.X, b.mesh.tets, b.surface});
    }
    // Rigid bodies (output.md): a surface-only body each (no tets; its surface posed per frame in
    // x, and so in the XDMF), after the soft bodies.
    for (std::size_t r = 0; r < model.rigid.size(); ++r) {
      const auto& body = model.rigid[r];
      const auto& initial = model.initial.rigid[r];
      Mat3X posed = (initial.orientation.toRotationMatrix() * body.surface.vertices).colwise() + initial.position;
      out_bodies.push_back({body.name, std::move(posed), Eigen::MatrixXi(4, 0), body.surface.triangles});
    }
    is_static = model.step.integrator == IntegratorKind::static_equilibrium;
    total = is_static ? model.step.static_load_steps : model.step.steps;
    every = std::max<long>(1, scene.output.every);
    {
      // What the run will write, checked before anything is (per frame: the series below; contact
      // rows are not known in advance).
      const long frames = is_static ? total + 1 : total / every + (total % every != 0 ? 1 : 0) + 1;
      double series = model.contact.enabled ? 8 + 4 + 8 : 0;
      for (const auto& a : model.actuation.actuators) series += a.has_measure() ? 16 : 8;
      series += 104.0 * static_cast<double>(model.rigid.size());  // position, orientation, velocity, angular_velocity
      series += 24.0 * static_cast<double>(model.actuation.effectors.size());
      check_output_space(out_path,
                         io::estimate_output(out_bodies, wo.write_v, wo.write_contact_force, frames, series,
                                             out_path.filename().string()),
                         frames, cb.warn);
    }
  }

  bool stop_requested() const { return cb.stop_requested && cb.stop_requested(); }
  void progress_update(long done) const {
    if (cb.progress_update) cb.progress_update(done);
  }
  void progress_clear() const {
    if (cb.progress_clear) cb.progress_clear();
  }
  // Where the frames of an unfinished run are (under writer_mutex).
  void report_unfinished() const {
    const std::string requested = out_path.string();
    const long frames = writer_ptr->frames_written();
    std::string where = (frames == 1 ? std::string("frame 0 is") : "frames 0-" + std::to_string(frames - 1) + " are") +
                        " in " + writer_ptr->final_path().string();
    if (writer_ptr->final_path() != std::filesystem::path(requested) && std::filesystem::exists(requested))
      where += " (" + requested + " is unchanged)";
    say(cb.note, where);
  }

  RunOutputResult run() {
    SOFTDIFF_DEMAND(!ran, "OutputRun::run() called twice");
    ran = true;
    Data& data = *data_ptr;
    RunOutputResult result;
    result.is_static = is_static;
    result.jacobian = theta.has_value();
    std::unique_lock<std::mutex> hold(writer_mutex);  // while the file and its datasets are created
    writer_ptr = std::make_unique<io::Hdf5Writer>(wo, out_bodies);
    io::Hdf5Writer& writer = *writer_ptr;
    State state = model.initial, next = model.initial;
    // Per-frame series of actuators (value, and cable length / closed-cavity volume) and effectors
    // (position).
    struct Series {
      int value = -1, measure = -1;
    };
    std::vector<Series> actuator_series;
    for (const auto& a : model.actuation.actuators) {
      Series s;
      s.value = writer.add_series("/actuators/" + a.name + "/value", 0, actuator_value_unit(a));
      if (a.has_measure())
        s.measure = writer.add_series("/actuators/" + a.name + "/" + a.measure_name(), 0, actuator_measure_unit(a));
      actuator_series.push_back(s);
    }
    std::vector<int> effector_series;
    for (const auto& e : model.actuation.effectors)
      effector_series.push_back(
          writer.add_series("/bodies/" + model.fem.bodies[e.body].name + "/effectors/" + e.name, 3, "m"));
    // Rigid bodies (output.md): /bodies/<r>/{position, orientation (w, x, y, z), velocity,
    // angular_velocity}, one row per frame; x (and v) of the whole output: the soft bodies' nodes,
    // then each rigid body's surface vertices posed by its state.
    struct RigidSeries {
      int position = -1, orientation = -1, velocity = -1, angular_velocity = -1;
    };
    std::vector<RigidSeries> rigid_series;
    long rigid_vertices = 0;
    for (const auto& r : model.rigid) {
      const std::string group = "/bodies/" + r.name;
      rigid_series.push_back({writer.add_series(group + "/position", 3, "m"),
                              writer.add_series(group + "/orientation", 4, "1"),
                              writer.add_series(group + "/velocity", 3, "m/s"),
                              writer.add_series(group + "/angular_velocity", 3, "rad/s")});
      rigid_vertices += r.surface.vertices.cols();
    }
    VecX x_out,
        v_out;  // soft x, v followed by the rigid surfaces' (sized once)
    if (!model.rigid.empty()) {
      x_out.resize(model.initial.x.size() + 3 * rigid_vertices);
      if (wo.write_v) v_out.resize(x_out.size());
    }
    auto pose_rigid_surfaces = [&](const State& st) {
      x_out.head(st.x.size()) = st.x;
      if (wo.write_v) v_out.head(st.v.size()) = st.v;
      Eigen::Index offset = st.x.size();
      for (std::size_t r = 0; r < model.rigid.size(); ++r) {
        const auto& body = model.rigid[r];
        const auto& rs = st.rigid[r];
        const Eigen::Index nv = body.surface.vertices.cols();
        Eigen::Map<Mat3X> x(x_out.data() + offset, 3, nv);
        x.noalias() = rs.orientation.toRotationMatrix() * body.surface.vertices;  // R p: the lever arms
        if (wo.write_v) {
          Eigen::Map<Mat3X> v(v_out.data() + offset, 3, nv);
          for (Eigen::Index i = 0; i < nv; ++i) v.col(i) = rs.velocity + rs.angular_velocity.cross(x.col(i));
        }
        x.colwise() += rs.position;
        offset += 3 * nv;
      }
    };
    // Contacts (output.md /contact/*, /solver/contact_*): the contacts of the step that produced
    // each frame (none at frame 0).
    struct ContactOutput {
      int offsets = -1, point = -1, frame = -1, force = -1, mode = -1, pair = -1, iterations = -1, residual = -1;
      std::int64_t rows = 0;
      std::vector<double> buffer;
      std::vector<std::int32_t> pairs;
      std::vector<std::int8_t> modes;
    } co;
    if (model.contact.enabled) {
      using E = io::Hdf5Writer::Element;
      writer.write_strings("/contact/names", model.contact.detection.names, "1");
      co.offsets = writer.add_table("/contact/offsets", {}, E::i64, "1");
      co.point = writer.add_table("/contact/point", {3}, E::f64, "m");
      co.frame = writer.add_table("/contact/frame", {3, 3}, E::f64, "1");
      co.force = writer.add_table("/contact/force", {3}, E::f64, "N");
      co.mode = writer.add_table("/contact/mode", {}, E::i8, "1");
      co.pair = writer.add_table("/contact/pair", {2}, E::i32, "1");
      co.iterations = writer.add_table("/solver/contact_iterations", {}, E::i32, "1");
      co.residual = writer.add_table("/solver/contact_residual", {}, E::f64, "1");
      writer.append_rows(co.offsets, &co.rows, 1);
    }
    auto write_contacts = [&](bool first) {
      if (!model.contact.enabled) return;
      const auto& cd = data.contact;
      const long nc = first ? 0 : cd.contacts.size();
      if (nc > 0) {
        co.buffer.resize(static_cast<std::size_t>(9 * nc));
        for (long i = 0; i < nc; ++i) Eigen::Map<Vec3>(&co.buffer[3 * i]) = cd.contacts.contacts[i].point;
        writer.append_rows(co.point, co.buffer.data(), nc);
        for (long i = 0; i < nc; ++i)  // row-major (3, 3): row r holds component r of t1, t2, n
          Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(&co.buffer[9 * i]) = cd.contacts.contacts[i].frame;
        writer.append_rows(co.frame, co.buffer.data(), nc);
        writer.append_rows(co.force, cd.lambda.data(), nc);
        co.modes.resize(static_cast<std::size_t>(nc));
        co.pairs.resize(static_cast<std::size_t>(2 * nc));
        for (long i = 0; i < nc; ++i) {
          co.modes[i] = static_cast<std::int8_t>(cd.modes[i]);
          co.pairs[2 * i] = cd.contacts.contacts[i].side_a;
          co.pairs[2 * i + 1] = cd.contacts.contacts[i].side_b;
        }
        writer.append_rows(co.mode, co.modes.data(), nc);
        writer.append_rows(co.pair, co.pairs.data(), nc);
      }
      co.rows += nc;
      writer.append_rows(co.offsets, &co.rows, 1);
      const std::int32_t iterations = first ? 0 : cd.result.iterations;
      const double residual = first || nc == 0 ? 0.0 : cd.result.residuals.max();
      writer.append_rows(co.iterations, &iterations, 1);
      writer.append_rows(co.residual, &residual, 1);
    };
    // /bodies/<b>/contact_force: the world force of each contact of the step that produced the
    // frame, C_i lambda_i = lambda_t1 t1 + lambda_t2 t2 + lambda_n n on the first side, spread over
    // the contact's nodes with its weights (barycentric on the first side, minus barycentric on the
    // second: the reaction), i.e. H_c^T lambda_c without the projection of fixed nodes. Zero at
    // frame 0. With rigid bodies, their surface vertices follow the soft nodes (the contact stage's
    // pseudo-nodes, in the order of x_out): /bodies/<rigid>/contact_force is the force on each
    // vertex.
    VecX nodal_contact_force = VecX::Zero(!model.contact.enabled ? 0
                                          : model.rigid.empty()  ? 3L * model.fem.num_nodes
                                                                 : x_out.size());
    auto compute_nodal_contact_force = [&](bool first) {
      nodal_contact_force.setZero();
      if (first) return;
      const auto& cd = data.contact;
      for (int i = 0; i < cd.contacts.size(); ++i) {
        const auto& c = cd.contacts.contacts[static_cast<std::size_t>(i)];
        const Vec3 world = c.frame * cd.lambda.segment<3>(3 * i);
        for (int k = 0; k < c.count; ++k)
          nodal_contact_force.segment<3>(3 * c.nodes[static_cast<std::size_t>(k)]) +=
              c.weights[static_cast<std::size_t>(k)] * world;
      }
    };
    auto write_frame = [&](const State& st, double step_seconds, bool first = false) {
      std::lock_guard<std::mutex> lock(writer_mutex);
      if (model.contact.enabled) compute_nodal_contact_force(first);
      if (model.rigid.empty()) {
        writer.append_frame(st.t, st.x, &st.v, step_seconds, model.contact.enabled ? &nodal_contact_force : nullptr);
      } else {
        pose_rigid_surfaces(st);
        writer.append_frame(st.t, x_out, wo.write_v ? &v_out : nullptr, step_seconds,
                            model.contact.enabled ? &nodal_contact_force : nullptr);
        for (std::size_t r = 0; r < model.rigid.size(); ++r) {
          const auto& rs = st.rigid[r];
          const double q[4] = {rs.orientation.w(), rs.orientation.x(), rs.orientation.y(), rs.orientation.z()};
          writer.append_series(rigid_series[r].position, rs.position.data());
          writer.append_series(rigid_series[r].orientation, q);
          writer.append_series(rigid_series[r].velocity, rs.velocity.data());
          writer.append_series(rigid_series[r].angular_velocity, rs.angular_velocity.data());
        }
      }
      write_contacts(first);
      for (size_t a = 0; a < actuator_series.size(); ++a) {
        const auto& act = model.actuation.actuators[a];
        double value = act.value.at(st.t);
        if (is_static && act.value.points.empty()) value *= st.t;  // static: constant values ramped by the load factor
        if (applied_set) value = applied[static_cast<Eigen::Index>(a)];
        writer.append_series(actuator_series[a].value, &value);
        if (actuator_series[a].measure >= 0) {
          const double m = act.measure(st.x);
          writer.append_series(actuator_series[a].measure, &m);
        }
      }
      for (size_t e = 0; e < effector_series.size(); ++e) {
        const Vec3 p = model.actuation.effectors[e].effector.position(st.x);
        writer.append_series(effector_series[e], p.data());
      }
      if (hooks.frame) hooks.frame(writer, st, data, first);
    };
    if (hooks.setup) hooks.setup(writer);
    hold.unlock();

    StepTimings timings;
    double output_seconds = 0, derivative_seconds = 0;
    // Contact derivatives (--jacobian): steps whose NCP derivative was rank-deficient (redundant
    // contacts: the minimum-norm solution was used), the largest deficiency, contacts whose
    // geometry derivative did not exist (counted, taken as zero), and contacts whose active feature
    // pair was not unique (the smoothed estimate).
    long rank_deficient_steps = 0, rank_deficiency_max = 0, nondifferentiable_total = 0, smoothed_total = 0;
    MatX static_jacobian;  // static scenes: dx*/dtheta (parameters, actuation)
    long steps_done = 0, warnings_newton = 0, warnings_contact = 0, contacts_total = 0, contacts_max = 0,
         contact_iterations = 0;
    StepStatus failure;
    std::string status = "complete";
    std::string run_error;  // a failure that is not the computation's (disk full, out of memory)
    if (cb.progress_start) cb.progress_start(total, o.progress_label);
    auto t_run = Clock::now();

    try {
      write_frame(state, 0.0, true);
      if (is_static) {
        auto t0 = Clock::now();
        step_in_progress = 1;
        failure = integrator::solve_static(model, data, state, next, [&](long s, const State& st) {
          const double step_seconds = seconds_since(t0);
          auto tw = Clock::now();
          write_frame(st, step_seconds);
          output_seconds += seconds_since(tw);
          steps_done = s;
          progress_update(s);
          if (stop_requested() && s < total) throw StopRequested{};
          step_in_progress = s + 1;
          t0 = Clock::now();
        });
        timings = data.timings;
        if (failure.ok()) state = next;
        if (failure.ok() && theta) {
          // The implicit function theorem at the final equilibrium (static_solver_derivatives.hpp).
          auto td = Clock::now();
          // A ComputationError of the derivative (the contact derivative's iterations,
          // contact_step_derivatives.cpp) is reported as the equilibrium's, with its load step.
          const std::string derivative_error =
              diff::static_jacobian(model, data, state, theta->layout, static_jacobian);
          if (!derivative_error.empty()) {
            failure.code = StepStatus::Code::solver_failed;
            failure.step = steps_done;
            failure.detail = derivative_error;
          }
          derivative_seconds += seconds_since(td);
        }
      } else {
        State previous;  // the state before `state` (BDF2), set after the first step
        const std::function<void(const std::string&)> warn_step = [&](const std::string& w) {
          progress_clear();
          say(cb.warn, w);
        };
        for (long k = 1; k <= total; ++k) {
          if (stop_requested()) {
            status = "interrupted";
            break;
          }
          step_in_progress = k;
          auto t0 = Clock::now();
          StepStatus s;
          if (hooks.actuation) {
            s = hooks.actuation(k, state, applied);
            applied_set = true;
          }
          if (s.ok())
            s = integrator::time_step(model, data, state, k > 1 ? &previous : nullptr, next, k,
                                      hooks.actuation ? &applied : nullptr);
          const double step_seconds = seconds_since(t0);
          failure = integrator::strict_or_warn(model, data, k, s, o.strict, warnings_newton, warnings_contact, warn_step);
          // The step's contacts, unless it failed before its contact solve was judged.
          if (model.contact.enabled && (failure.ok() || failure.code == StepStatus::Code::contact_not_converged)) {
            const auto& cd = data.contact;
            contacts_total += cd.contacts.size();
            contacts_max = std::max<long>(contacts_max, cd.contacts.size());
            contact_iterations += cd.result.iterations;
          }
          timings += data.timings;
          if (!failure.ok()) break;
          if (sensitivity) {
            auto td = Clock::now();
            // A ComputationError of the derivative (the contact derivative's iterations,
            // contact_step_derivatives.cpp) is reported as the step's, with its number.
            std::string derivative_error;
            bool derivative_ok = false;
            try {
              derivative_ok = sensitivity->advance(model, data, state, next);
            } catch (const ComputationError& e) {
              derivative_error = e.what();
            }
            if (!derivative_ok) {
              failure.code = StepStatus::Code::solver_failed;
              failure.step = k;
              failure.detail = derivative_error.empty() ? "the derivative of the step failed (a linear solve "
                                                          "did not succeed or gave non-finite values)"
                                                        : "the derivative of the step failed: " + derivative_error;
              break;
            }
            derivative_seconds += seconds_since(td);
            if (model.contact.enabled && !data.contact.contacts.empty()) {
              const auto& sd = sensitivity->step();
              const int deficiency = sd.ncp_derivative().rank_deficiency();
              rank_deficient_steps += deficiency > 0;
              rank_deficiency_max = std::max<long>(rank_deficiency_max, deficiency);
              nondifferentiable_total += sd.nondifferentiable_contacts();
              smoothed_total += sd.smoothed_contacts();
            }
          }
          std::swap(previous, state);  // BDF2's history
          std::swap(state, next);
          steps_done = k;
          if (k % every == 0 || k == total) {
            auto tw = Clock::now();
            write_frame(state, step_seconds);
            output_seconds += seconds_since(tw);
          }
          progress_update(k);
          step_in_progress = 0;
        }
      }
    } catch (const StopRequested&) {
      status = "interrupted";
    } catch (const ComputationError& e) {
      run_error = e.what();
    } catch (const std::bad_alloc&) {
      run_error = "out of memory";
    }
    step_in_progress = 0;
    progress_clear();
    const double run_seconds = seconds_since(t_run);
    const auto fill = [&](RunOutputResult& res) {
      res.path = writer.final_path().string();
      res.steps_done = steps_done;
      res.frames = writer.frames_written();
      res.run_seconds = run_seconds;
      res.setup_seconds = setup_seconds;
      res.derivative_seconds = derivative_seconds;
      res.output_seconds = output_seconds;
      res.timings = timings;
      res.factorizations = data.factorizations;
      res.solver = data.solver->counters();
      res.rank_deficient_steps = rank_deficient_steps;
      res.rank_deficiency_max = rank_deficiency_max;
      res.nondifferentiable_contacts = nondifferentiable_total;
      res.smoothed_contacts = smoothed_total;
      res.newton_not_converged_steps = warnings_newton;
      res.contact_not_converged_steps = warnings_contact;
      res.contacts_total = contacts_total;
      res.contacts_max = contacts_max;
      res.contact_iterations = contact_iterations;
      res.state = state;
    };
    // A run that did not complete: the file is finished (unfinished, its side files).
    const auto done = [&](const std::string& message) {
      result.ok = false;
      result.status = status == "interrupted" ? status : std::string("failed");
      result.error = message;
      fill(result);
      return result;
    };

    // 3. Finish the file. A second signal now waits for this and then does nothing.
    std::unique_lock<std::mutex> finishing(writer_mutex);
    writer_done = true;
    const auto finish_unfinished = [&](const std::string& final_status) {
      try {
        writer.finish(final_status);
      } catch (const std::exception& e) {
        say(cb.error, e.what());
      }
      report_unfinished();
    };
    // "failed: no space left on device after frame 39"
    const auto failed_status = [&](const std::string& message, const std::string& when) {
      if (writer.failure().empty()) return "failed: " + message + " " + when;
      std::string reason = writer.failure();  // the system's text: "No space left on device"
      reason[0] = static_cast<char>(std::tolower(static_cast<unsigned char>(reason[0])));
      return "failed: " + reason + " " + when;
    };
    if (!run_error.empty()) {
      say(cb.error, run_error);
      finish_unfinished(failed_status(run_error, "after frame " + std::to_string(writer.frames_written() - 1)));
      return done(run_error);
    }
    if (!failure.ok()) {
      const std::string reason = describe(model, failure);
      say(cb.error, reason);
      finish_unfinished("diverged: " + reason);
      return done(reason);
    }
    try {
      if (theta && status == "complete") {
        // output.md: /jacobians/<theta> (3 n_total, k) = d x_T / d theta at the final frame.
        const std::int64_t frame = writer.frames_written() - 1;
        const MatX& J = is_static ? static_jacobian : sensitivity->dx_dtheta();
        const char* method = is_static ? "implicit function theorem at the equilibrium" : "forward sensitivities";
        for (const auto& g : theta->groups) {
          std::string names;
          for (const auto& c : g.columns) names += (names.empty() ? "" : ",") + c;
          writer.write_matrix("/jacobians/" + g.name, J.middleCols(g.offset, g.size), jacobian_units(model, g),
                              {{"theta", names},
                               {"frame", frame},
                               {"method", std::string(method)},
                               {"ncp_rank_deficient_steps", std::int64_t{rank_deficient_steps}},
                               {"nondifferentiable_contacts", std::int64_t{nondifferentiable_total}},
                               {"smoothed_contacts", std::int64_t{smoothed_total}}});
        }
      }
      if (hooks.finish && status == "complete") hooks.finish(writer);
    } catch (const ComputationError& e) {
      say(cb.error, e.what());
      finish_unfinished(failed_status(e.what(), "while writing the results of the run"));
      return done(e.what());
    }
    if (status == "interrupted") {
      const std::string message =
          "interrupted after " + std::to_string(steps_done) + (is_static ? " load steps" : " steps");
      say(cb.error, message);
      finish_unfinished(status);
      return done(message);
    }
    writer.finish(status);  // a failure here (ComputationError) says where the frames are
    finishing.unlock();
    result.ok = true;
    result.status = status;
    fill(result);
    return result;
  }
};

OutputRun::OutputRun(const RunOutputOptions& o, const SceneDesc& scene, const Model& model, Clock::time_point t_setup,
                     RunHooks hooks, RunCallbacks callbacks)
    : impl_(std::make_unique<Impl>(o, scene, model, t_setup, std::move(hooks), std::move(callbacks))) {}

OutputRun::~OutputRun() = default;

const std::filesystem::path& OutputRun::output_path() const { return impl_->out_path; }
bool OutputRun::is_static() const { return impl_->is_static; }
long OutputRun::step_in_progress() const { return impl_->step_in_progress.load(); }
RunOutputResult OutputRun::run() { return impl_->run(); }

bool OutputRun::abandon(const std::string& message) {
  Impl& r = *impl_;
  std::lock_guard<std::mutex> lock(r.writer_mutex);
  if (r.writer_done) return false;  // the run is finishing by itself
  r.writer_done = true;
  say(r.cb.error, message);
  if (r.writer_ptr) {
    try {
      r.writer_ptr->finish("interrupted");
    } catch (const std::exception& e) {
      say(r.cb.error, e.what());
    }
    r.report_unfinished();
  }
  return true;
}

}  // namespace softdiff::io
