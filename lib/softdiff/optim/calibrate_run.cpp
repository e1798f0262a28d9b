// `softdiff calibrate` as a library call: calibrate_run.hpp. Moved from
// app/cmd_calibrate.cpp (2026-12-04, branch pycal), the messages unchanged.
#include <softdiff/optim/calibrate_run.hpp>

#include <softdiff/actuation/embedding.hpp>
#include <softdiff/collision/distance.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/core/parameters.hpp>
#include <softdiff/core/text.hpp>
#include <softdiff/diff/parameters.hpp>
#include <softdiff/diff/theta_selection.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/run_output.hpp>
#include <softdiff/io/units.hpp>
#include <softdiff/io/target_files.hpp>
#include <softdiff/rigid/rigid_derivatives.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <sstream>

namespace softdiff::optim {

namespace {

using diff::parse_theta;


struct Calibrated {
  std::vector<ParameterId> ids;
  std::vector<rigid::RigidParameterId> rigid_ids;  // after ids in the values (issue 21)
  std::vector<std::string> names;  // output names: "young", or "beam.young" when several bodies have it; then
                                   // the rigid ones: "cube.mass", "cube.inertia.xx"
};

// --param: young, poisson, density, rayleigh_mass, rayleigh_stiffness, friction; a kind
// alone is every body (every contact pair rule for friction), BODY.kind one body.
// Rigid bodies (issue 21): mass, inertia (its diagonal components in body axes: xx, yy,
// zz; inertia.xx one of them), alone every rigid body, RIGID.kind one; identified in log
// scale. Off-diagonal components are refused (not positive: no log scale).
Calibrated parse_params(const std::string& list, const Model& model) {
  const std::string valid = "young, poisson, density, rayleigh_mass, rayleigh_stiffness, friction, and for rigid bodies "
                            "mass, inertia, inertia.xx, inertia.yy, inertia.zz (or BODY.NAME)";
  const std::vector<std::string> items = split_list(list);
  if (items.empty() || (items.size() == 1 && items[0].empty()))
    throw InputError("--param: expected a comma-separated list of " + valid + "; got nothing");
  Calibrated c;
  std::set<std::string> kinds;
  const int nb = static_cast<int>(model.fem.bodies.size());
  const auto& rules = model.contact.detection.pairs;
  const auto& names = model.contact.detection.names;
  auto add = [&](const ParameterId& id, const std::string& name) {
    for (const auto& e : c.ids)
      if (e.kind == id.kind && e.body == id.body) throw InputError("--param " + list + ": '" + name + "' is listed twice");
    c.ids.push_back(id);
    c.names.push_back(name);
  };
  const int nr = static_cast<int>(model.rigid.size());
  std::vector<std::string> rigid_names;
  std::set<std::string> rigid_kinds;
  const auto add_rigid = [&](int r, int index) {
    const std::string name = model.rigid[static_cast<std::size_t>(r)].name + "." + rigid::rigid_parameter_name(index);
    for (const auto& e : c.rigid_ids)
      if (e.body == r && e.index == index) throw InputError("--param " + list + ": '" + name + "' is listed twice");
    c.rigid_ids.push_back({r, index});
    rigid_names.push_back(name);
  };
  for (const auto& item : items) {
    if (item.empty()) throw InputError("--param " + list + ": empty name in the list (expected " + valid + ")");
    std::string body, kind = item;
    if (item != "inertia" && item.rfind("inertia.", 0) != 0)
      if (const auto dot = item.find('.'); dot != std::string::npos) {
        body = item.substr(0, dot);
        kind = item.substr(dot + 1);
      }
    if (kind == "mass" || kind == "inertia" || kind.rfind("inertia.", 0) == 0) {
      // A rigid body's parameter (issue 21).
      std::vector<int> indices;
      if (kind == "mass") indices = {0};
      else if (kind == "inertia") indices = {1, 2, 3};
      else if (kind == "inertia.xx") indices = {1};
      else if (kind == "inertia.yy") indices = {2};
      else if (kind == "inertia.zz") indices = {3};
      else if (kind == "inertia.xy" || kind == "inertia.xz" || kind == "inertia.yz")
        throw InputError("--param " + item + ": off-diagonal inertia components are not calibrated (they need not be "
                         "positive, and parameters are identified in log scale): use inertia (xx, yy, zz) or "
                         "inertia.xx, inertia.yy, inertia.zz");
      else
        throw InputError("--param " + list + ": unknown parameter '" + kind + "' (expected " + valid + ")");
      if (nr == 0)
        throw InputError("--param " + item + ": '" + kind + "' is a rigid body's parameter, and this scene has no rigid "
                         "body (a soft body's mass: density)");
      std::vector<std::string> rigid_bodies;
      int found = -1;
      for (int r = 0; r < nr; ++r) {
        rigid_bodies.push_back(model.rigid[static_cast<std::size_t>(r)].name);
        if (rigid_bodies.back() == body) found = r;
      }
      if (!body.empty() && found < 0) {
        for (const auto& b : model.fem.bodies)
          if (b.name == body)
            throw InputError("--param " + item + ": '" + body + "' is a soft body; " + kind +
                             " is a rigid body's parameter (rigid bodies: " + io::join(rigid_bodies) +
                             "; a soft body's mass: density)");
        std::string msg = "--param " + item + ": no rigid body '" + body + "' (rigid bodies: " + io::join(rigid_bodies) + ")";
        if (const auto m = io::closest_match(body, rigid_bodies)) msg += "; did you mean '" + *m + "'?";
        throw InputError(msg);
      }
      for (int r = 0; r < nr; ++r)
        if (body.empty() || r == found)
          for (const int index : indices) add_rigid(r, index);
      rigid_kinds.insert(kind == "mass" ? "mass" : "inertia");
      continue;
    }
    const auto p = parse_parameter(kind);
    if (!p) throw InputError("--param " + list + ": unknown parameter '" + kind + "' (expected " + valid + ")");
    kinds.insert(kind);
    if (*p == Parameter::friction) {
      if (!model.contact.enabled || rules.empty())
        throw InputError("--param: 'friction' needs contact, and this scene has none");
      if (!body.empty()) throw InputError("--param " + item + ": friction is per contact pair, not per body: use 'friction'");
      for (int r = 0; r < static_cast<int>(rules.size()); ++r)
        add({*p, r}, rules.size() == 1 ? "friction"
                                       : names[static_cast<std::size_t>(rules[static_cast<std::size_t>(r)].a)] + "-" +
                                             names[static_cast<std::size_t>(rules[static_cast<std::size_t>(r)].b)] +
                                             ".friction");
      continue;
    }
    if (body.empty()) {
      for (int b = 0; b < nb; ++b) add({*p, b}, nb == 1 ? kind : model.fem.bodies[static_cast<std::size_t>(b)].name + "." + kind);
    } else {
      int found = -1;
      std::vector<std::string> bodies;
      for (int b = 0; b < nb; ++b) {
        bodies.push_back(model.fem.bodies[static_cast<std::size_t>(b)].name);
        if (bodies.back() == body) found = b;
      }
      if (found < 0) {
        for (const auto& rb : model.rigid)
          if (rb.name == body)
            throw InputError("--param " + item + ": '" + body + "' is a rigid body; its parameters are mass and "
                             "inertia (" + kind + " is a soft body's)");
        std::string msg = "--param " + item + ": no body '" + body + "' (bodies: " + io::join(bodies) + ")";
        if (const auto m = io::closest_match(body, bodies)) msg += "; did you mean '" + *m + "'?";
        throw InputError(msg);
      }
      add({*p, found}, nb == 1 ? kind : body + "." + kind);
    }
  }
  // Whether this scene's step is differentiated (the checks of --jacobian).
  std::string plain;
  for (const auto& k : kinds) plain += (plain.empty() ? "" : ",") + k;
  for (const auto& k : rigid_kinds) plain += (plain.empty() ? "" : ",") + k;
  parse_theta("--param", plain, model);
  c.names.insert(c.names.end(), rigid_names.begin(), rigid_names.end());
  return c;
}

// The scene step of a target time; fails if it is not a multiple of dt.
long step_of(const std::string& file, const std::string& what, double t, double dt) {
  const double k = std::round(t / dt);
  if (std::abs(t - k * dt) > 1e-6 * dt) {
    std::ostringstream s;
    s.precision(10);
    s << file << ": " << what << " at time " << t << " s is not a multiple of the scene's dt (" << dt
      << " s): simulate the target with the scene's dt, or --set simulation.dt=...";
    throw InputError(s.str());
  }
  return static_cast<long>(k);
}

// The frames of a trajectory target: --frames last | all | K,K,... (indices into the
// file's frames; frame 0, the initial state, does not depend on the parameters).
std::vector<long> select_frames(const std::string& option, long count, bool is_static, const std::string& file) {
  if (is_static) {
    if (option != "last" && option != "all")
      throw InputError("--frames " + option + ": a static scene has one equilibrium, the target's last frame "
                       "(--frames last)");
    return {count - 1};
  }
  if (count < 2) throw InputError(file + ": the target has no frame after the initial state");
  if (option == "last") return {count - 1};
  std::vector<long> out;
  if (option == "all") {
    for (long k = 1; k < count; ++k) out.push_back(k);
    return out;
  }
  for (const auto& item : split_list(option)) {
    char* end = nullptr;
    const long k = std::strtol(item.c_str(), &end, 10);
    if (item.empty() || *end != '\0')
      throw InputError("--frames " + option + ": expected last, all or a list of frame indices, got '" + item + "'");
    if (k == 0) throw InputError("--frames " + option + ": frame 0 is the initial state, which does not depend on the parameters");
    if (k < 0 || k >= count)
      throw InputError("--frames " + option + ": frame " + item + " is not in the target (" + file + " has frames 0.." +
                       std::to_string(count - 1) + ")");
    out.push_back(k);
  }
  std::sort(out.begin(), out.end());
  if (std::adjacent_find(out.begin(), out.end()) != out.end()) throw InputError("--frames " + option + ": a frame is listed twice");
  return out;
}

CalibrationTarget trajectory_target(const CalibrateRunOptions& o, const Model& model, const MessageSink& note) {
  const io::TrajectoryFile f = io::read_trajectory(o.target, model);
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  const std::vector<long> frames = select_frames(o.frames, static_cast<long>(f.times.size()), is_static, o.target);
  CalibrationTarget t;
  for (const long k : frames) {
    const long step = is_static ? 1 : step_of(o.target, "frame " + std::to_string(k), f.times[static_cast<std::size_t>(k)], model.step.dt);
    if (!is_static && step < 1)
      throw InputError(o.target + ": frame " + std::to_string(k) + " is at time 0 (the initial state)");
    t.frames.push_back(step);
    t.states.push_back(f.x[static_cast<std::size_t>(k)]);
  }
  // Rigid bodies' poses (issue 21): those in the file; their orientation rows scaled by
  // the scene's L (rigid_orientation_length).
  for (const auto& rt : f.rigid) {
    CalibrationTarget::RigidPoses pose;
    pose.body = rt.body;
    pose.length = rigid_orientation_length(model.rigid[static_cast<std::size_t>(rt.body)]);
    for (const long k : frames) {
      pose.position.push_back(rt.position[static_cast<std::size_t>(k)]);
      pose.orientation.push_back(rt.orientation[static_cast<std::size_t>(k)]);
    }
    t.rigid.push_back(std::move(pose));
  }
  for (const auto& name : f.rigid_missing)
    if (note) note("rigid body '" + name + "': no /bodies/" + name + "/position, orientation in " + o.target +
         ": its pose is not matched");
  for (const auto& pose : t.rigid) {
    std::ostringstream s;
    s.precision(4);
    s << "rigid body '" << model.rigid[static_cast<std::size_t>(pose.body)].name
      << "': its pose is matched (orientation rows scaled by L = " << pose.length << " m)";
    if (note) note(s.str());
  }
  for (std::size_t i = 1; i < t.frames.size(); ++i)
    if (t.frames[i] == t.frames[i - 1]) throw InputError(o.target + ": two frames at the same step " + std::to_string(t.frames[i]));
  return t;
}

// A marker's place on a rigid body at its initial pose s0 (issue 21): the point in
// body axes (relative to the centre of mass), its distance to the body (0 inside: the
// winding number of the closed surface, Van Oosterom and Strackee's solid angles), and
// the distance allowed outside (half the nearest triangle's longest edge).
struct RigidMarkerPlace {
  Vec3 body_point = Vec3::Zero();
  double distance = 0, allowed = 0;
};
RigidMarkerPlace rigid_marker_distance(const rigid::RigidBody& body, const rigid::RigidState& s0, const Vec3& y) {
  RigidMarkerPlace out;
  out.body_point = s0.orientation.conjugate() * (y - s0.position);
  const auto& V = body.surface.vertices;
  const auto& T = body.surface.triangles;
  double solid = 0, best2 = std::numeric_limits<double>::infinity();
  for (Eigen::Index t = 0; t < T.cols(); ++t) {
    const Vec3 A = V.col(T(0, t)), B = V.col(T(1, t)), C = V.col(T(2, t));
    const Vec3 a = A - out.body_point, b = B - out.body_point, c = C - out.body_point;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    solid += 2 * std::atan2(a.dot(b.cross(c)), la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la);
    const double d2 = collision::point_triangle_closest(out.body_point, A, B, C).dist2;
    if (d2 < best2) {
      best2 = d2;
      out.allowed = 0.5 * std::max({(B - A).norm(), (C - B).norm(), (A - C).norm()});
    }
  }
  const bool inside = std::abs(solid) > 2 * M_PI;  // winding number |solid / 4 pi| > 1/2
  out.distance = inside ? 0.0 : std::sqrt(best2);
  return out;
}

// Markers: a scene effector of that name, else the marker's observation at time 0
// locates it in the body that contains it (at rest): a soft body's tet, or a point
// fixed on a rigid body.
CalibrationTarget marker_target(const CalibrateRunOptions& o, const Model& model) {
  const auto obs = io::read_markers(o.markers);
  const bool is_static = model.step.integrator == IntegratorKind::static_equilibrium;
  CalibrationTarget t;
  std::map<std::string, int> index;
  std::vector<std::unique_ptr<actuation::PointLocator>> locators;
  for (const auto& b : model.fem.bodies)
    locators.push_back(b.mesh.order == 2 ? std::make_unique<actuation::PointLocator>(b.mesh.X, b.mesh.tets, b.mesh.tets10)
                                         : std::make_unique<actuation::PointLocator>(b.mesh.X, b.mesh.tets));
  std::map<std::string, const io::MarkerObservation*> at_zero;
  for (const auto& ob : obs)
    if (ob.time == 0 && !at_zero.count(ob.marker)) at_zero[ob.marker] = &ob;
  auto marker_of = [&](const io::MarkerObservation& ob) {
    if (const auto it = index.find(ob.marker); it != index.end()) return it->second;
    Marker m;
    m.name = ob.marker;
    bool found = false;
    for (const auto& e : model.actuation.effectors)
      if (e.name == ob.marker) {
        m.point = e.effector.point();
        found = true;
      }
    if (!found) {
      const auto z = at_zero.find(ob.marker);
      if (z == at_zero.end())
        throw InputError(o.markers + ":" + std::to_string(ob.line) + ": marker '" + ob.marker +
                         "' is neither an effector of the scene nor observed at time 0 (where its position embeds it in "
                         "the body)");
      double best = std::numeric_limits<double>::infinity();
      for (std::size_t b = 0; b < locators.size(); ++b) {
        const auto r = locators[b]->locate(z->second->position);
        if (r.status == actuation::LocateStatus::inside || r.status == actuation::LocateStatus::outside) {
          if (r.embedding.outside_distance < best) {
            best = r.embedding.outside_distance;
            m.point = actuation::embedded_point(r.embedding, *locators[b], model.fem.bodies[b].node_begin);
            found = true;
          }
        }
      }
      // Rigid bodies (issue 21): inside the body's surface, or outside within half the
      // nearest triangle's longest edge (as a soft body's nearest tet): a point fixed on
      // the body, nearer than any soft body's.
      for (std::size_t r = 0; r < model.rigid.size(); ++r) {
        const auto near = rigid_marker_distance(model.rigid[r], model.initial.rigid[r], z->second->position);
        if (near.distance <= near.allowed && near.distance < best) {
          best = near.distance;
          m.rigid_body = static_cast<int>(r);
          m.body_point = near.body_point;
          found = true;
        }
      }
      if (!found)
        throw InputError(o.markers + ":" + std::to_string(z->second->line) + ": marker '" + ob.marker +
                         "' at time 0 is not inside any body (positions are world coordinates in metres)");
    }
    t.markers.push_back(m);
    index[ob.marker] = static_cast<int>(t.markers.size()) - 1;
    return static_cast<int>(t.markers.size()) - 1;
  };
  // Steps of the observations (time 0 only embeds markers).
  std::vector<std::pair<long, const io::MarkerObservation*>> used;
  for (const auto& ob : obs) {
    marker_of(ob);  // every marker is embedded, whether or not observed after time 0
    if (ob.time == 0) continue;
    const long step = is_static ? 1 : step_of(o.markers + ":" + std::to_string(ob.line), "the observation", ob.time, model.step.dt);
    used.push_back({step, &ob});
  }
  if (used.empty()) throw InputError(o.markers + ": no observation after time 0");
  std::stable_sort(used.begin(), used.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  for (const auto& [step, ob] : used) {
    if (t.frames.empty() || t.frames.back() != step) t.frames.push_back(step);
    t.observations.push_back({static_cast<int>(t.frames.size()) - 1, index.at(ob->marker), ob->position});
  }
  if (is_static && t.frames.size() != 1) throw InputError(o.markers + ": a static scene has one equilibrium (one time)");
  return t;
}

}  // namespace

CalibrationProblem prepare_calibration(const CalibrateRunOptions& o, const MessageSink& warn, const MessageSink& note) {
  if (o.target.empty() && o.markers.empty()) throw InputError("calibrate: give the observations with --target FILE.h5 or --markers FILE.csv");
  if (!o.markers.empty() && o.frames != "all") throw InputError("--frames selects frames of --target; with --markers every observed time is used");
  CalibrationProblem p;
  p.scene = io::load_scene(o.scene, o.set);
  io::BuildReport report;
  report.strict = o.strict;
  p.model = io::build_model(p.scene, &report);
  const Model& model = p.model;
  if (warn)
    for (const auto& w : report.warnings) warn(w);
  // Rigid bodies and rigidified parts: parse_theta's checks (issue 21; parts: implicit Euler
  // and BDF2, Newton too, either contact backend, rigid bodies in contact included, except
  // a limited joint in contact on the sparse backend or under Newton).
  Calibrated params = parse_params(o.param, model);
  p.ids = std::move(params.ids);
  p.rigid_ids = std::move(params.rigid_ids);
  p.names = std::move(params.names);

  // Initial values.
  std::vector<double>& init = p.init;
  if (!o.init.empty()) {
    const auto items = split_list(o.init);
    if (items.size() != p.names.size())
      throw InputError("--init " + o.init + ": expected " + std::to_string(p.names.size()) + " values (one per parameter: " +
                       io::join(p.names) + "), got " + std::to_string(items.size()));
    for (std::size_t j = 0; j < items.size(); ++j) {
      char* end = nullptr;
      const double v = std::strtod(items[j].c_str(), &end);
      if (items[j].empty() || *end != '\0' || !std::isfinite(v))
        throw InputError("--init " + o.init + ": '" + items[j] + "' is not a number");
      init.push_back(v);
    }
  } else {
    for (const auto& id : p.ids) init.push_back(diff::get_parameter(model, id));
    for (const auto& id : p.rigid_ids)
      init.push_back(rigid::get_parameter(model.rigid[static_cast<std::size_t>(id.body)], id.index));
  }
  for (std::size_t j = 0; j < init.size(); ++j) {
    const bool poisson = j < p.ids.size() && p.ids[j].kind == Parameter::poisson;
    if (poisson ? !(init[j] > 0 && init[j] < 0.5) : !(init[j] > 0))
      throw InputError("--init: " + p.names[j] + " = " + io::format_number(init[j]) + " is outside the calibrated range (" +
                       (poisson ? "0 < poisson < 0.5" : "> 0: it is identified in log scale") + ")");
  }

  p.target = o.markers.empty() ? trajectory_target(o, model, note) : marker_target(o, model);
  if (p.target.frames.size() == 1 && model.step.integrator != IntegratorKind::static_equilibrium && warn)
    warn("a single frame as target: the cost of an oscillating motion can have spurious minima (docs/method.md, "
         "\"Calibration\"); --frames all matches the whole trajectory");
  for (const auto& pose : p.target.rigid) p.rigid_matched.push_back(model.rigid[static_cast<std::size_t>(pose.body)].name);
  return p;
}

CalibrationOptions calibration_options(const CalibrateRunOptions& o) {
  CalibrationOptions co;
  co.max_iterations = o.max_iterations;
  co.ftol = o.tolerance;
  co.xtol = o.tolerance;
  co.strict = o.strict;
  return co;
}

Model calibrated_model(const CalibrationProblem& problem, const std::vector<double>& values) {
  Model final_model = problem.model;
  for (std::size_t j = 0; j < problem.ids.size(); ++j) diff::set_parameter(final_model, problem.ids[j], values[j]);
  for (std::size_t j = 0; j < problem.rigid_ids.size(); ++j) {
    const auto& id = problem.rigid_ids[j];
    rigid::set_parameter(final_model.rigid[static_cast<std::size_t>(id.body)], id.index, values[problem.ids.size() + j]);
  }
  return final_model;
}

std::string calibration_output_path(const CalibrateRunOptions& o, const std::string& output, bool force,
                                    const io::SceneDesc& scene) {
  std::filesystem::path out_path = output;
  if (out_path.empty()) out_path = std::filesystem::path(o.scene).stem().string() + "_calibrated.h5";
  std::error_code ec;
  if (std::filesystem::exists(out_path, ec) && !force)
    throw InputError(out_path.string() + ": exists (use --force to overwrite)");
  // Checked before the identification runs (the final run checks the scene's files
  // again before writing).
  std::vector<std::string> inputs = io::scene_input_files(scene);
  inputs.push_back(o.target);
  inputs.push_back(o.markers);
  io::check_output_is_not_input(out_path.string(), inputs);
  return out_path.string();
}

void write_calibration(io::Hdf5Writer& w, const CalibrationProblem& problem, const CalibrationResult& result) {
  using io::column_units;
  using io::parameter_unit;
  const Eigen::Index p = static_cast<Eigen::Index>(problem.names.size());
  MatX table(static_cast<Eigen::Index>(result.history.size()), p + 5);
  std::string columns = "iteration";
  for (const auto& n : problem.names) columns += "," + n;
  columns += ",cost,gradient_norm,damping,seconds";
  for (std::size_t i = 0; i < result.history.size(); ++i) {
    const auto& h = result.history[i];
    const Eigen::Index r = static_cast<Eigen::Index>(i);
    table(r, 0) = h.iteration;
    for (Eigen::Index j = 0; j < p; ++j) table(r, 1 + j) = h.values[static_cast<std::size_t>(j)];
    table(r, p + 1) = h.cost;
    table(r, p + 2) = h.gradient_norm;
    table(r, p + 3) = h.damping;
    table(r, p + 4) = h.seconds;
  }
  // Units per column: iteration 1, each parameter's, cost m^2 (1/2 |r|^2, r in m),
  // gradient_norm m^2 per the parameters' unit (|J^T r|; "mixed" when they differ),
  // damping 1, seconds s.
  std::vector<std::string> parameter_units;
  for (const auto& id : problem.ids) parameter_units.push_back(parameter_unit(id.kind));
  for (const auto& id : problem.rigid_ids) parameter_units.push_back(id.index == 0 ? "kg" : "kg m^2");
  std::vector<std::string> units{"1"};
  units.insert(units.end(), parameter_units.begin(), parameter_units.end());
  const std::string common = column_units(parameter_units);
  const std::map<std::string, std::string> m2_per{
      {"Pa", "m^2/Pa"}, {"1", "m^2"}, {"kg/m^3", "m^5/kg"}, {"1/s", "m^2 s"}, {"s", "m^2/s"}, {"kg", "m^2/kg"}, {"kg m^2", "1/kg"}};
  const auto gradient = m2_per.find(common);
  units.insert(units.end(), {"m^2", gradient == m2_per.end() ? std::string("mixed") : gradient->second, "1", "s"});
  w.write_matrix("/calibration/iterations", table, column_units(units), {{"columns", columns}});
  for (std::size_t j = 0; j < problem.names.size(); ++j) w.set_attribute("/calibration", problem.names[j], result.values[j]);
  w.set_attribute("/calibration", "converged", std::int64_t{result.converged ? 1 : 0});
  w.set_attribute("/calibration", "iterations", std::int64_t{result.iterations});
  w.set_attribute("/calibration", "final_cost", result.cost);
  w.set_attribute("/calibration", "stop_reason", result.stop_reason);
  w.set_attribute("/calibration", "evaluations", std::int64_t{result.evaluations});
}

}  // namespace softdiff::optim
