#include <softdiff/io/build_model.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/io/plausibility.hpp>
#include <softdiff/actuation/embedding.hpp>
#include <softdiff/collision/obstacle.hpp>
#include <softdiff/contact/rigid_contact.hpp>
#include <softdiff/rigid/rigid_body.hpp>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <unordered_map>

namespace softdiff::io {

Mat3 rotation_from_euler_deg(const Vec3& a) {
  const double k = std::numbers::pi / 180.0;
  return (Eigen::AngleAxisd(a.z() * k, Vec3::UnitZ()) * Eigen::AngleAxisd(a.y() * k, Vec3::UnitY()) *
          Eigen::AngleAxisd(a.x() * k, Vec3::UnitX()))
      .toRotationMatrix();
}

namespace {

[[noreturn]] void fail(const Where& where, const std::string& message) {
  throw InputError(where.str() + ": " + message);
}

std::string group_list(const mesh::TetMesh& m) {
  std::string s;
  for (const auto& g : m.groups) {
    if (g.name.empty()) continue;
    if (!s.empty()) s += ", ";
    s += "'" + g.name + "'";
  }
  return s.empty() ? "the mesh has no named physical groups" : "groups: " + s;
}

// Local nodes selected by a box (world coordinates), a physical group or a list of
// file node indices; an empty selection is an error at `f.where`.
std::vector<int> select_nodes(const FixedDesc& f, const std::string& body, const mesh::TetMesh& m,
                              std::unordered_map<long, int>& by_file_index) {
  const Vec3 lo = m.X.rowwise().minCoeff(), hi = m.X.rowwise().maxCoeff();
  const double tol = 1e-9 * (hi - lo).norm();
  std::vector<int> nodes;
  switch (f.kind) {
    case FixedDesc::Kind::box:
      for (int i = 0; i < m.num_nodes(); ++i) {
        const Vec3 p = m.X.col(i);
        bool inside = true;
        for (int c = 0; c < 3; ++c) inside = inside && p[c] >= f.box[c] - tol && p[c] <= f.box[c + 3] + tol;
        if (inside) nodes.push_back(i);
      }
      if (nodes.empty()) {
        std::ostringstream s;
        s.precision(6);
        s << "box selects no node of body '" << body << "' (its nodes span [" << lo.x() << ", " << lo.y() << ", "
          << lo.z() << "] to [" << hi.x() << ", " << hi.y() << ", " << hi.z()
          << "] after mesh_scale/rotate_deg/translate)";
        fail(f.where, s.str());
      }
      break;
    case FixedDesc::Kind::group: {
      const auto* g = m.find_group(f.group);
      if (!g) fail(f.where, "mesh " + m.source + " has no physical group '" + f.group + "' (" + group_list(m) + ")");
      if (g->nodes.empty()) fail(f.where, "physical group '" + f.group + "' has no node on the tetrahedral mesh");
      nodes = g->nodes;
      break;
    }
    case FixedDesc::Kind::nodes:
      if (by_file_index.empty())
        for (int i = 0; i < m.num_nodes(); ++i) by_file_index[m.file_index[i]] = i;
      for (long k : f.nodes) {
        auto it = by_file_index.find(k);
        if (it == by_file_index.end())
          fail(f.where, "node " + std::to_string(k) + " is not a node of a tetrahedron of " + m.source + " (" +
                            std::to_string(m.num_nodes() + m.orphan_nodes) + " nodes in the file)");
        nodes.push_back(it->second);
      }
      break;
  }
  return nodes;
}

// Marks the fixed dofs of one body (local node indices).
void resolve_fixed(const BodyDesc& body, const mesh::TetMesh& m, std::vector<unsigned char>& fixed_local) {
  std::unordered_map<long, int> by_file_index;
  for (const auto& f : body.fixed)
    for (int i : select_nodes(f, body.name, m, by_file_index))
      for (int c = 0; c < 3; ++c)
        if (f.axes[c]) fixed_local[3 * i + c] = 1;
}

// Rigidified parts of one body (scene.md `rigidify`): the local nodes of each free or
// servo-attached part (`parts`, with the entry index), attach: fixed parts marked in
// fixed_local. Errors: a node in two parts, a node in a part and in `fixed`, a part
// whose nodes are on one line (no rotation would move them: its reduced matrix would be
// singular), an attach that is neither free, fixed nor one of the body's servos.
struct PendingPart {
  std::size_t body = 0, entry = 0;
  std::vector<int> nodes;  // local, sorted
};

void resolve_rigidify(const BodyDesc& body, std::size_t body_index, const mesh::TetMesh& m,
                      std::vector<unsigned char>& fixed_local, std::vector<PendingPart>& parts) {
  if (body.rigidify.empty()) return;
  std::unordered_map<long, int> by_file_index;
  std::vector<int> owner(static_cast<std::size_t>(m.num_nodes()), -1);
  std::vector<std::vector<int>> selected;
  for (std::size_t k = 0; k < body.rigidify.size(); ++k) {
    const RigidifyDesc& rd = body.rigidify[k];
    std::vector<int> nodes = select_nodes(rd.nodes, body.name, m, by_file_index);
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    for (int i : nodes) {
      const std::string node = "node " + std::to_string(m.file_index[static_cast<std::size_t>(i)]);
      if (owner[static_cast<std::size_t>(i)] >= 0)
        fail(rd.where, node + " of body '" + body.name + "' is also in rigidify[" +
                           std::to_string(owner[static_cast<std::size_t>(i)]) +
                           "]: a node belongs to at most one rigidified part (merge the two selections)");
      for (int c = 0; c < 3; ++c)
        if (fixed_local[static_cast<std::size_t>(3 * i + c)])
          fail(rd.where, node + " of body '" + body.name +
                             "' is also fixed (bodies[].fixed): a node is either fixed or in a rigidified part (use "
                             "attach: fixed to hold the part)");
      owner[static_cast<std::size_t>(i)] = static_cast<int>(k);
    }
    // Nodes on one line (or fewer than three): a rotation about that line moves none.
    Vec3 mean = Vec3::Zero();
    for (int i : nodes) mean += m.X.col(i);
    mean /= static_cast<double>(nodes.size());
    Mat3 cov = Mat3::Zero();
    for (int i : nodes) cov += (m.X.col(i) - mean) * (m.X.col(i) - mean).transpose();
    const Vec3 ev = Eigen::SelfAdjointEigenSolver<Mat3>(cov).eigenvalues();  // ascending
    if (nodes.size() < 3 || !(ev[1] > 1e-12 * ev[2]))
      fail(rd.where, "the part's " + std::to_string(nodes.size()) + " node(s) of body '" + body.name +
                         "' lie on one line: a rigidified part needs three nodes not on a line");
    if (rd.attach != "free" && rd.attach != "fixed") {
      const ActuatorDesc* servo = nullptr;
      std::string servos;
      for (const auto& a : body.actuators) {
        if (a.kind != ActuatorDesc::Kind::servo) continue;
        servos += (servos.empty() ? "'" : ", '") + a.name + "'";
        if (a.name == rd.attach) servo = &a;
      }
      if (!servo)
        fail(rd.attach_where, "'" + rd.attach + "' is neither free, fixed nor a servo of body '" + body.name + "' (" +
                                  (servos.empty() ? std::string("it has no servo") : "its servos: " + servos) + ")");
    }
    selected.push_back(std::move(nodes));
  }
  for (std::size_t k = 0; k < body.rigidify.size(); ++k) {
    if (body.rigidify[k].attach == "fixed") {
      for (int i : selected[k])
        for (int c = 0; c < 3; ++c) fixed_local[static_cast<std::size_t>(3 * i + c)] = 1;
    } else {
      parts.push_back({body_index, k, std::move(selected[k])});
    }
  }
}

// The model's rigidified parts (after build_fem_model and build_actuation): global
// nodes, masses, the attached servo (whose nodes must all be in the part: its whole
// force then acts on the part, as the wrench P^T f), the coupling entries.
void build_rigidified_parts(const SceneDesc& scene, const std::vector<PendingPart>& pending,
                            const std::vector<unsigned char>& fixed, Model& model) {
  auto& fem = model.fem;
  for (const PendingPart& pp : pending) {
    const BodyDesc& bd = scene.bodies[pp.body];
    const RigidifyDesc& rd = bd.rigidify[pp.entry];
    const auto& b = fem.bodies[pp.body];
    integrator::RigidifiedPart part;
    part.name = "body '" + bd.name + "' rigidify[" + std::to_string(pp.entry) + "]";
    part.body = static_cast<int>(pp.body);
    for (int i : pp.nodes) part.nodes.push_back(b.node_begin + i);
    if (rd.attach != "free") {
      const auto& acts = model.actuation.actuators;
      for (std::size_t a = 0; a < acts.size(); ++a)
        if (acts[a].body == part.body && acts[a].name == rd.attach) part.servo = static_cast<int>(a);
      SOFTDIFF_DEMAND(part.servo >= 0, "rigidify: attached servo not found");
      const auto& servo = std::get<actuation::Servo>(acts[static_cast<std::size_t>(part.servo)].kind);
      for (int i : servo.nodes())
        if (!std::binary_search(part.nodes.begin(), part.nodes.end(), i))
          fail(rd.attach_where, "servo '" + rd.attach + "' acts on node " +
                                    std::to_string(b.mesh.file_index[static_cast<std::size_t>(i - b.node_begin)]) +
                                    ", outside the part: an attached servo's nodes must all be in the part");
    }
    model.rigidify.parts.push_back(std::move(part));
  }
  fem.fixed = fixed;
  fem.num_fixed_dofs = std::count(fixed.begin(), fixed.end(), 1);
  integrator::build_rigidify(fem, model.rigidify);
}

std::string format_mm(double metres) {
  std::ostringstream s;
  s.precision(3);
  s << metres * 1e3 << " mm";
  return s.str();
}

// Embeds a world point in a body: inside, or outside within the locator's tolerance
// (a warning: extrapolated weights, as SOFA's BarycentricMapping), else an error.
actuation::EmbeddedPoint embed(const actuation::PointLocator& locator, const fem::BodyModel& b, const Vec3& p,
                               const Where& where, const std::string& what, BuildReport* report) {
  const auto r = locator.locate(p);
  if (r.status == actuation::LocateStatus::too_far || r.status == actuation::LocateStatus::no_tets) {
    std::ostringstream s;
    s << what << " lies " << format_mm(r.embedding.outside_distance) << " outside body '" << b.name
      << "' (more than the allowed " << format_mm(r.allowed_distance)
      << ", half the nearest element's longest edge); points are world coordinates in metres, after the body's "
         "mesh_scale/rotate_deg/translate";
    fail(where, s.str());
  }
  if (r.status == actuation::LocateStatus::outside && report)
    report->warnings.push_back(where.str() + ": " + what + " lies " + format_mm(r.embedding.outside_distance) +
                               " outside body '" + b.name + "': mapped to its nearest tetrahedron (" +
                               std::to_string(r.embedding.tet) +
                               (locator.order() == 2 ? ") with extrapolated reference coordinates (quadratic shape functions)"
                                                     : ") with extrapolated barycentric weights"));
  return actuation::embedded_point(r.embedding, locator, b.node_begin);
}

// Runs before build_fem_model (the cables' stiffness cliques enter the pattern):
// `bodies` hold the world rest meshes and their global node offsets (node_begin).
void build_actuation(const SceneDesc& scene, const std::vector<fem::BodyModel>& bodies, Model& model,
                     BuildReport* report) {
  int num_nodes = 0;
  for (const auto& b : bodies) num_nodes += b.mesh.num_nodes();
  VecX rest(3 * num_nodes);
  for (const auto& b : bodies)
    rest.segment(3 * b.node_begin, 3 * b.mesh.num_nodes()) =
        Eigen::Map<const VecX>(b.mesh.X.data(), 3 * b.mesh.num_nodes());
  for (size_t bi = 0; bi < scene.bodies.size(); ++bi) {
    const BodyDesc& bd = scene.bodies[bi];
    const fem::BodyModel& b = bodies[bi];
    if (bd.actuators.empty() && bd.effectors.empty()) continue;
    // Quadratic bodies embed points with the quadratic shape functions (embedding.hpp).
    const actuation::PointLocator locator = b.mesh.order == 2
                                                ? actuation::PointLocator(b.mesh.X, b.mesh.tets, b.mesh.tets10)
                                                : actuation::PointLocator(b.mesh.X, b.mesh.tets);
    std::unordered_map<long, int> by_file_index;
    for (const ActuatorDesc& ad : bd.actuators) {
      actuation::ActuatorModel a;
      a.name = ad.name;
      a.body = static_cast<int>(bi);
      a.value.constant = ad.value;
      a.value.points = ad.schedule;
      if (ad.limits) {
        a.has_limits = true;
        a.limits = *ad.limits;
      }
      switch (ad.kind) {
        case ActuatorDesc::Kind::cable: {
          std::vector<actuation::EmbeddedPoint> points;
          for (size_t k = 0; k < ad.points.size(); ++k) {
            Where w = ad.where;
            w.path += ".points[" + std::to_string(k) + "]";
            points.push_back(embed(locator, b, ad.points[k], w, "cable point " + std::to_string(k), report));
          }
          a.kind = actuation::Cable(std::move(points), ad.pull_point);
          break;
        }
        case ActuatorDesc::Kind::pressure: {
          Where w = ad.where;
          w.path += ".surface";
          const mesh::PhysicalGroup* g = b.mesh.find_group(ad.surface);
          if (!g) fail(w, "mesh " + b.mesh.source + " has no physical group '" + ad.surface + "' (" + group_list(b.mesh) + ")");
          if (g->triangles.empty())
            fail(w, "physical group '" + ad.surface + "' has no triangle on the body (a cavity is a group of boundary triangles)");
          Triangles tris(3, static_cast<int>(g->triangles.size()));
          for (size_t k = 0; k < g->triangles.size(); ++k) tris.col(static_cast<int>(k)) = b.mesh.triangles.col(g->triangles[k]);
          actuation::Cavity cavity;
          // Quadratic bodies: the 6-node triangles (mid-edge nodes from the tets' edges).
          const mesh::Triangles6 tris6 = b.mesh.order == 2 ? mesh::quadratic_triangles(b.mesh, tris) : mesh::Triangles6();
          const auto status = actuation::Cavity::create(b.mesh.X, b.mesh.tets, tris, b.node_begin, cavity,
                                                        b.mesh.order == 2 ? &tris6 : nullptr);
          if (!status.ok()) fail(w, "cavity '" + ad.surface + "': " + status.message());
          a.kind = std::move(cavity);
          break;
        }
        case ActuatorDesc::Kind::servo: {
          std::vector<int> nodes = select_nodes(ad.nodes, bd.name, b.mesh, by_file_index);
          for (int& i : nodes) i += b.node_begin;
          actuation::Servo servo;
          const auto status = ad.rotation ? actuation::Servo::rotation(nodes, ad.direction, ad.center, rest, servo)
                                          : actuation::Servo::translation(nodes, ad.direction, rest, servo);
          if (!status.ok()) fail(ad.where, "servo '" + ad.name + "': " + status.message());
          a.kind = std::move(servo);
          break;
        }
      }
      model.actuation.actuators.push_back(std::move(a));
    }
    for (const EffectorDesc& ed : bd.effectors) {
      Where w = ed.where;
      w.path += ".point";
      model.actuation.effectors.push_back(
          {ed.name, static_cast<int>(bi), actuation::Effector(embed(locator, b, ed.point, w, "effector point", report))});
    }
  }
}

}  // namespace

collision::Obstacle build_obstacle(const ObstacleDesc& d) {
  collision::Obstacle o;
  o.name = d.name;
  using K = ObstacleDesc::Kind;
  using S = collision::ShapeKind;
  switch (d.kind) {
    case K::plane: o.kind = S::plane; break;
    case K::box: o.kind = S::box; break;
    case K::sphere: o.kind = S::sphere; break;
    case K::capsule: o.kind = S::capsule; break;
    case K::cylinder: o.kind = S::cylinder; break;
    case K::mesh: o.kind = S::mesh; break;
  }
  o.normal = d.normal;
  o.offset = d.offset;
  o.offset_schedule = d.offset_schedule;
  o.center = d.center;
  o.rotation = rotation_from_euler_deg(d.rotate_deg);
  o.half_extents = d.half_extents;
  o.radius = d.radius;
  o.half_length = d.half_length;
  try {
    if (d.kind == K::mesh) o.mesh = collision::read_triangle_surface(d.mesh, d.mesh_scale);
    collision::prepare(o);
  } catch (const InputError& e) {
    fail(d.where, e.what());
  }
  return o;
}

// Contact: obstacles, body surfaces in global node indices, pair rules (scene.md
// `contact`; the rules of scene.cpp's header), solver options.
void build_contact(const SceneDesc& scene, Model& model) {
  const ContactDesc& c = scene.contact;
  if (!c.enabled) return;
  auto& settings = model.contact;
  settings.enabled = true;
  auto& det = settings.detection;
  det.margin = c.margin;
  for (const auto& b : model.fem.bodies) {
    collision::BodySurface s = collision::make_surface(b.name, b.surface, b.node_begin);
    det.surfaces.push_back(std::move(s));
    det.names.push_back(b.name);
  }
  // Rigid bodies (docs/method.md "Rigid bodies in contact"): their surface vertices are
  // pseudo-nodes after the soft nodes; names are soft bodies, rigid bodies, obstacles.
  const int num_soft = static_cast<int>(model.fem.bodies.size());
  contact::add_rigid_surfaces(model);
  for (const auto& od : scene.obstacles) {
    det.obstacles.push_back(build_obstacle(od));
    det.names.push_back(od.name);
  }
  auto index_of = [&](const std::string& name) {
    return static_cast<int>(std::find(det.names.begin(), det.names.end(), name) - det.names.begin());
  };
  const int num_bodies = static_cast<int>(det.surfaces.size());  // soft and rigid
  if (c.pairs.empty()) {
    for (int b = 0; b < num_soft; ++b)
      for (int o = 0; o < static_cast<int>(scene.obstacles.size()); ++o) det.pairs.push_back({b, num_bodies + o, c.friction});
    // scene.md: every soft body with every rigid body, every rigid body with every obstacle.
    for (int b = 0; b < num_soft; ++b)
      for (int r = num_soft; r < num_bodies; ++r) det.pairs.push_back({b, r, c.friction});
    for (int r = num_soft; r < num_bodies; ++r)
      for (int o = 0; o < static_cast<int>(scene.obstacles.size()); ++o) det.pairs.push_back({r, num_bodies + o, c.friction});
  }
  for (const auto& p : c.pairs) det.pairs.push_back({index_of(p.first), index_of(p.second), p.mu});
  if (c.self_collision)
    for (int b = 0; b < num_soft; ++b) {
      const bool listed = std::any_of(det.pairs.begin(), det.pairs.end(), [&](const auto& r) { return r.a == b && r.b == b; });
      if (!listed) det.pairs.push_back({b, b, c.friction});
    }
  settings.ncp.solver = c.solver == ContactDesc::Solver::pgs ? contact::NcpSolverKind::pgs : contact::NcpSolverKind::admm;
  settings.ncp.tolerance = c.tolerance;
  settings.ncp.max_iterations = c.max_iterations;
  settings.ncp.polish = c.polish;
  settings.ncp.polish_at_scale_always = c.polish_at_scale_always;
  settings.ncp.backend = c.backend == ContactDesc::Backend::dense    ? contact::NcpBackend::dense
                         : c.backend == ContactDesc::Backend::sparse ? contact::NcpBackend::sparse
                                                                     : contact::NcpBackend::automatic;
  settings.ncp.dense_max_contacts = c.dense_max_contacts;
  if (c.derivative_dense_max_active >= 0) settings.ncp.derivative_dense_max_active = c.derivative_dense_max_active;
  if (c.derivative_mixed_dense_max_active >= 0)
    settings.ncp.derivative_mixed_dense_max_active = c.derivative_mixed_dense_max_active;
  if (c.derivative_scale_iterations >= 1) settings.ncp.derivative_scale_max_iterations = c.derivative_scale_iterations;
  settings.smoothing.samples = c.smoothing_samples;
  settings.smoothing.sigma = c.smoothing_sigma > 0 ? c.smoothing_sigma : 0.1 * c.margin;
  settings.smoothing.seed = static_cast<std::uint64_t>(c.smoothing_seed);
}

// A rigid body of the scene (scene.md `type: rigid`): its shape (a mesh shape read as
// a closed surface, oriented outward), mass properties (from the density, or as
// given: then the centre of mass is still the uniform-density one, the shape's
// geometric centroid), its surface tessellation, joint, and initial state
// (rigid::initialize). Messages carry the scene location.
namespace {

rigid::RigidBody build_rigid_body(const RigidBodyDesc& d, rigid::RigidState& initial) {
  rigid::RigidBody r;
  r.name = d.name;
  rigid::Shape& shape = r.shape;
  using K = RigidShapeDesc::Kind;
  using S = rigid::Shape::Kind;
  shape.kind = d.shape.kind == K::box       ? S::box
               : d.shape.kind == K::sphere  ? S::sphere
               : d.shape.kind == K::capsule ? S::capsule
               : d.shape.kind == K::cylinder ? S::cylinder
                                            : S::mesh;
  shape.half_extents = d.shape.half_extents;
  shape.radius = d.shape.radius;
  shape.length = d.shape.length;
  if (shape.kind == S::mesh) {
    collision::TriangleSurface surface;
    try {
      surface = collision::read_triangle_surface(d.shape.mesh, d.shape.mesh_scale);
    } catch (const InputError& e) {  // "FILE: open edge ..." -> with the scene location first
      fail(d.shape.mesh_where, e.what());
    }
    // Outward: gmsh orients a surface by its own normal, not by the enclosed volume.
    double volume6 = 0;
    for (Eigen::Index t = 0; t < surface.triangles.cols(); ++t)
      volume6 += surface.vertices.col(surface.triangles(0, t))
                     .dot(surface.vertices.col(surface.triangles(1, t)).cross(surface.vertices.col(surface.triangles(2, t))));
    if (volume6 < 0) surface.triangles.row(1).swap(surface.triangles.row(2));
    shape.mesh_vertices = std::move(surface.vertices);
    shape.mesh_triangles = std::move(surface.triangles);
  }
  rigid::MassProperties mp;
  try {
    mp = rigid::mass_properties(shape, d.density.value_or(1.0));
  } catch (const std::invalid_argument& e) {
    fail(shape.kind == S::mesh ? d.shape.mesh_where : d.shape.where, e.what());
  }
  if (d.density) {
    r.mass = mp.mass;
    r.inertia = mp.inertia;
  } else {
    r.mass = d.mass;
    r.inertia = d.inertia;
  }
  // Curved primitives: max_edge r / 4, i.e. ceil(2 pi 4) = 26 segments around the circumference.
  const double max_edge = shape.kind == S::box || shape.kind == S::mesh ? 0.0 : 0.25 * shape.radius;
  r.surface = rigid::tessellate(shape, mp.centre, max_edge);

  initial.position = d.position;
  initial.orientation = Eigen::Quaterniond(d.orientation[0], d.orientation[1], d.orientation[2], d.orientation[3]);
  initial.orientation.normalize();
  initial.velocity = d.velocity;
  initial.angular_velocity = d.angular_velocity;
  if (d.joint) {
    using J = JointDesc::Kind;
    r.joint.kind = d.joint->kind == J::hinge    ? rigid::Joint::Kind::hinge
                   : d.joint->kind == J::slider ? rigid::Joint::Kind::slider
                                                : rigid::Joint::Kind::fixed;
    r.joint.anchor = d.joint->anchor;
    r.joint.axis = d.joint->axis;
    if (d.joint->limits) r.joint.limits = std::make_pair((*d.joint->limits)[0], (*d.joint->limits)[1]);
  }
  try {
    rigid::initialize(r, initial);
  } catch (const std::invalid_argument& e) {
    fail(d.joint ? d.joint->where : d.where, e.what());
  }
  initial = r.reference;  // the initial velocity projected onto the joint's motion
  return r;
}

}  // namespace

Model build_model(const SceneDesc& scene, BuildReport* report) {
  Model model;
  model.name = scene.name;
  const auto& sim = scene.simulation;
  model.step.integrator = sim.integrator == Integrator::static_equilibrium ? IntegratorKind::static_equilibrium
                           : sim.integrator == Integrator::bdf2            ? IntegratorKind::bdf2
                                                                           : IntegratorKind::implicit_euler;
  model.step.dt = sim.dt;
  model.step.steps = sim.steps;
  model.step.gravity = sim.gravity;
  model.step.newton_iterations = sim.newton_iterations;
  model.step.newton_tolerance = sim.newton_tolerance;
  model.step.static_max_iterations = sim.static_max_iterations;
  model.step.static_tolerance = sim.static_tolerance;
  model.step.static_displacement_tolerance = sim.static_answer_criterion ? sim.static_displacement_tolerance : 0.0;
  model.step.static_residual_tolerance = sim.static_answer_criterion ? sim.static_residual_tolerance : 0.0;
  model.step.static_load_steps = sim.static_load_steps;
  model.step.static_friction = sim.static_friction_load_step ? StaticFriction::load_step : StaticFriction::iterate;
  switch (scene.linear_solver.kind) {
    case LinearSolverKind::cholmod: model.solver.kind = integrator::SolverKind::cholmod; break;
    case LinearSolverKind::ldlt: model.solver.kind = integrator::SolverKind::ldlt; break;
    case LinearSolverKind::cg: model.solver.kind = integrator::SolverKind::cg; break;
  }
  model.solver.cg_tolerance = scene.linear_solver.cg_tolerance;
  model.solver.cg_max_iterations = scene.linear_solver.cg_max_iterations;
  model.solver.factor_reuse = scene.linear_solver.factor_reuse;
  model.solver.pcg_tolerance = scene.linear_solver.pcg_tolerance;
  model.solver.pcg_max_iterations = scene.linear_solver.pcg_max_iterations;
  model.solver.refactor_iterations = scene.linear_solver.refactor_iterations;

  // A scene of rigid bodies only has no soft node: the step skips the soft stage
  // (integrator/bdf2.cpp time_step_rigid_only).
  if (scene.bodies.empty() && scene.rigid_bodies.empty())
    fail(Where{scene.file.string(), 0, 0, "bodies"}, "the scene has no body");
  std::vector<fem::BodyModel> bodies;
  std::vector<unsigned char> fixed;
  std::vector<PendingPart> pending_parts;  // free and servo-attached rigidified parts
  std::vector<Vec3> initial_velocity;
  for (const auto& bd : scene.bodies) {
    fem::BodyModel b;
    b.name = bd.name;
    b.mesh = read_gmsh(bd.mesh);
    if (bd.elements == ElementOrder::linear && b.mesh.order == 2)
      fail(bd.elements_where, "linear elements on the quadratic mesh " + b.mesh.source +
                                  " are not supported; mesh it with `gmsh -3 -order 1` or remove `elements: linear`");
    if (bd.elements == ElementOrder::quadratic && b.mesh.order == 1) mesh::elevate_to_quadratic(b.mesh);
    if (report) {
      if (b.mesh.orphan_nodes > 0)
        report->warnings.push_back(b.mesh.source + ": " + std::to_string(b.mesh.orphan_nodes) +
                                   " nodes belong to no tetrahedron and were dropped (output node order = file order "
                                   "of the remaining nodes)");
      if (b.mesh.reoriented_tets > 0)
        report->warnings.push_back(b.mesh.source + ": " + std::to_string(b.mesh.reoriented_tets) +
                                   " tetrahedra had negative orientation and were reordered");
    }
    const Mat3 R = rotation_from_euler_deg(bd.rotate_deg);
    b.mesh.X = (R * (bd.mesh_scale * b.mesh.X)).colwise() + bd.translate;
    b.surface = mesh::boundary_triangles(b.mesh.tets);
    if (b.mesh.order == 2) {
      // Collision sees each 6-node boundary face as four linear triangles whose
      // vertices are mesh nodes (method.md, "Quadratic tetrahedra": contact).
      b.surface6 = mesh::quadratic_triangles(b.mesh, b.surface);
      b.surface = mesh::split_quadratic_triangles(b.surface6);
    }
    b.law = bd.material.law;
    b.young = bd.material.young;
    b.poisson = bd.material.poisson;
    b.density = bd.material.density;
    b.rayleigh_mass = bd.rayleigh_mass;
    b.rayleigh_stiffness = bd.rayleigh_stiffness;
    b.psd_projection = bd.psd_projection;
    b.mass_kind = bd.mass == MassKind::consistent ? fem::MassKind::consistent : fem::MassKind::lumped;
    std::vector<unsigned char> fixed_local(3 * b.mesh.num_nodes(), 0);
    resolve_fixed(bd, b.mesh, fixed_local);
    resolve_rigidify(bd, bodies.size(), b.mesh, fixed_local, pending_parts);
    // A body in a contact pair with an obstacle or another body may rest on it (the
    // static solver's proximal term, docs/method.md "Static equilibrium").
    const auto& cdesc = scene.contact;
    const bool held_by_contact =
        cdesc.enabled && (cdesc.pairs.empty() ? !scene.obstacles.empty()
                                              : std::any_of(cdesc.pairs.begin(), cdesc.pairs.end(), [&](const auto& p) {
                                                  return p.first != p.second && (p.first == bd.name || p.second == bd.name);
                                                }));
    if (sim.integrator == Integrator::static_equilibrium && !held_by_contact &&
        std::find(fixed_local.begin(), fixed_local.end(), 1) == fixed_local.end()) {
      Where w = bd.where;
      w.path += ".fixed";
      fail(w, "a static scene needs fixed nodes on every body not in a contact pair: body '" + bd.name +
                  "' is free, so it has no equilibrium under load");
    }
    fixed.insert(fixed.end(), fixed_local.begin(), fixed_local.end());
    initial_velocity.push_back(bd.initial_velocity);
    bodies.push_back(std::move(b));
  }
  int node_begin = 0;
  for (auto& b : bodies) {
    b.node_begin = node_begin;  // as build_fem_model numbers them
    node_begin += b.mesh.num_nodes();
  }
  build_actuation(scene, bodies, model, report);
  // The cables' stiffness blocks are needed by the static solver's tangent only; the
  // dynamic step (the paper's, actuation at x_i) would just carry their fill-in
  // (+34% nonzeros in the Trunk's Cholesky factor).
  const bool is_static = sim.integrator == Integrator::static_equilibrium;
  // Rigidified parts: their dofs get identity rows in the factorized matrix like fixed
  // dofs (the pattern's fixed_* lists), fem.fixed stays the fixed dofs alone.
  std::vector<unsigned char> fixed_or_rigid = fixed;
  for (const PendingPart& pp : pending_parts)
    for (int i : pp.nodes)
      for (int c = 0; c < 3; ++c)
        fixed_or_rigid[static_cast<std::size_t>(3 * (bodies[pp.body].node_begin + i) + c)] = 1;
  fem::build_fem_model(std::move(bodies), fixed_or_rigid, sim.gravity, model.fem,
                       is_static ? model.actuation.stiffness_cliques() : std::vector<std::vector<int>>{});
  if (!pending_parts.empty()) build_rigidified_parts(scene, pending_parts, fixed, model);

  for (const auto& rd : scene.rigid_bodies) {  // before build_contact: their surfaces join detection
    rigid::RigidState initial;
    model.rigid.push_back(build_rigid_body(rd, initial));
    model.initial.rigid.push_back(initial);
  }
  build_contact(scene, model);

  const int ndof = 3 * model.fem.num_nodes;
  model.initial.t = 0;
  model.initial.x = Eigen::Map<const VecX>(model.fem.X.data(), ndof);
  model.initial.v = VecX::Zero(ndof);
  for (size_t bi = 0; bi < model.fem.bodies.size(); ++bi) {
    const auto& b = model.fem.bodies[bi];
    for (int i = b.node_begin; i < b.node_begin + b.num_nodes; ++i) model.initial.v.segment<3>(3 * i) = initial_velocity[bi];
  }
  for (int k = 0; k < ndof; ++k)
    if (model.fem.fixed[k]) model.initial.v[k] = 0;
  if (report) {
    std::vector<std::string> implausible;
    check_plausibility(scene, model, implausible, report->warnings);
    if (report->strict && !implausible.empty())
      throw InputError(implausible.front() + " (--strict: an implausible size or mass is an error)");
    report->warnings.insert(report->warnings.end(), implausible.begin(), implausible.end());
  }
  return model;
}

}  // namespace softdiff::io
