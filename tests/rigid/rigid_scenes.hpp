#pragma once
// The set-ups shared by the rigid-body tests (issue 21; tests/rigid and the rigid tests of
// tests/app), as tests/optim/rigid_calibration_scene.hpp: scene builders and helpers that
// several test files repeated word for word (`duplicates --change --base e65241c`, D1-D8
// of session 10). Set-up only: no assertion lives here. Everything is inline (the test
// binaries are unity builds: several files that include this share one translation unit).
#include <softdiff/data.hpp>
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/io/build_model.hpp>
#include <softdiff/io/scene.hpp>
#include <softdiff/model.hpp>
#include <support/cli.hpp>
#include <support/meshes.hpp>
#include <support/rigid_contact.hpp>

#include <gtest/gtest.h>

#include <cstdio>
#include <iostream>
#include <random>
#include <filesystem>
#include <sstream>
#include <string>
#include <unistd.h>
#include <utility>
#include <vector>

namespace softdiff::test::rigid_scenes {

// A soft anchor far away (a 1x1x1-box mesh of 1 cm at (5, 5, 5)) with every node fixed,
// gravity (0, 0, -g), step h: the soft body a scene with rigid bodies in contact is built
// around where the test wants the soft stage present; it takes part in no contact pair.
inline Model anchored(double h, double g = 9.81) {
  BodySpec spec;
  spec.fixed = [](const Vec3&) { return true; };
  mesh::TetMesh m = box_mesh(1, 1, 1, 0.01, 0.01, 0.01);
  for (Eigen::Index i = 0; i < m.X.cols(); ++i) m.X.col(i) += Vec3(5, 5, 5);
  return make_model(m, spec, Vec3(0, 0, -g), h);
}

// A model without soft bodies (test::make_model of no body: 0 nodes, an empty pattern),
// gravity (0, 0, -g), step h: a scene of rigid bodies only.
inline Model rigid_only_model(double h, double g = 9.81) {
  return make_model(std::vector<BodyInput>{}, Vec3(0, 0, -g), h);
}

// A tetrahedron (base triangle (0,0,0), (0.1,0,0), (0,0.08,0), apex (0.03,0.03,0.05) m):
// three contacts on a plane, determinate (a box's four corners are not).
inline rigid::Shape wedge_shape() {
  rigid::Shape s;
  s.kind = rigid::Shape::Kind::mesh;
  s.mesh_vertices.resize(3, 4);
  s.mesh_vertices << 0, 0.1, 0, 0.03, 0, 0, 0.08, 0.03, 0, 0, 0, 0.05;
  s.mesh_triangles.resize(3, 4);
  s.mesh_triangles << 0, 0, 1, 2, 2, 1, 2, 0, 1, 3, 3, 3;
  return s;
}

// The wedge (800 kg/m^3) standing on its base on z = 0, sliding at (0.5, 0.1, 0) m/s and
// spinning at 0.8 rad/s about z: appended to `model` as "wedge".
inline void add_sliding_wedge(Model& model) {
  const rigid::Shape shape = wedge_shape();
  const rigid::MassProperties mp = rigid::mass_properties(shape, 800);
  rigid::RigidState s;
  s.position = Vec3(0, 0, mp.centre.z());
  s.velocity = Vec3(0.5, 0.1, 0);
  s.angular_velocity = Vec3(0, 0, 0.8);
  add_rigid_body(model, "wedge", shape, 800, s);
}

// A tight NCP: `tolerance`, 5000 iterations (the polish then solves the mode equations to
// round-off, so that finite differences and closed forms see the exact solution).
inline contact::NcpOptions tight_ncp(double tolerance) {
  contact::NcpOptions o;
  o.tolerance = tolerance;
  o.max_iterations = 5000;
  return o;
}

// Sum of the world contact forces of the last contact solve on side `side` (a name index:
// soft bodies, rigid bodies, obstacles): + when it is side a, the reaction when side b;
// `count`: the number of its contacts.
inline Vec3 contact_force_on(const Data& data, int side, int* count = nullptr) {
  Vec3 f = Vec3::Zero();
  int k = 0;
  for (int i = 0; i < data.contact.contacts.size(); ++i) {
    const auto& c = data.contact.contacts.contacts[static_cast<std::size_t>(i)];
    const Vec3 w = c.frame * data.contact.lambda.segment<3>(3 * i);
    if (c.side_a == side) f += w, ++k;
    else if (c.side_b == side) f -= w, ++k;
  }
  if (count) *count = k;
  return f;
}

// The damped soft slab's material (E = 50 kPa, nu = 0.4, 1000 kg/m^3, Rayleigh 20 1/s and
// 0.01 s), bottom (z = 0) fixed: the slab under the rigid cube of the cube-on-slab tests.
inline BodySpec damped_slab_spec() {
  BodySpec spec;
  spec.young = 5e4;
  spec.poisson = 0.4;
  spec.density = 1000;
  spec.rayleigh_mass = 20;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& p) { return p.z() < 1e-9; };
  return spec;
}

// The static rigid tests' cube on a soft slab (validation_rigid_static.cpp, the static
// derivatives' test): the slab 0.12 x 0.12 x 0.01 m (8 x 8 x 2 boxes, damped_slab_spec),
// a rigid 40 mm cube (500 kg/m^3) resting on it at zero gap at (0.06, 0.06, 0.03), contact
// margin 1e-3, the pair rule body-cube mu 0.5, gravity g (default (0, 0, -9.81)), step h.
inline Model slab_and_cube(double h, const Vec3& g = Vec3(0, 0, -9.81)) {
  const BodySpec spec = damped_slab_spec();
  const mesh::TetMesh m = box_mesh(8, 8, 2, 0.12, 0.12, 0.01);
  Model model = make_model(m, spec, g, h);
  rigid::RigidState s;
  s.position = Vec3(0.06, 0.06, 0.01 + 0.02);  // resting on the slab at zero gap
  add_rigid_body(model, "cube", box_shape(Vec3(0.02, 0.02, 0.02)), 500, s);
  enable_rigid_contact(model, {}, {{"body", "cube", 0.5}}, 1e-3, contact::NcpOptions{});
  return model;
}

// The slab of slab_and_cube under the 40 mm cube tilted by 0.15 rad about (1, 0.7, 0) on a
// vertical slider (its rotation held), frictionless, its lowest corner 0.2 mm above the
// slab (within the margin): at rest it stands on that corner (the static derivatives'
// slider test: a determinate contact, no face lying on a face).
inline Model tilted_cube_on_slab_slider(double h) {
  Model model = slab_and_cube(h);
  auto& cube = model.rigid[0];
  rigid::RigidState s = model.initial.rigid[0];
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.15, Vec3(1, 0.7, 0).normalized()));
  double lowest = 0;
  for (int c = 0; c < 8; ++c) {
    const Vec3 corner(c & 1 ? 0.02 : -0.02, c & 2 ? 0.02 : -0.02, c & 4 ? 0.02 : -0.02);
    lowest = std::min(lowest, (s.orientation * corner).z());
  }
  s.position = Vec3(0.06, 0.06, 0.01 - lowest + 2e-4);
  cube.joint.kind = rigid::Joint::Kind::slider;
  cube.joint.axis = Vec3::UnitZ();
  rigid::initialize(cube, s);
  model.initial.rigid[0] = cube.reference;
  for (auto& r : model.contact.detection.pairs) r.mu = 0;
  return model;
}

// The free 40 mm cube of slab_and_cube (500 kg/m^3, at zero gap on the slab) leaning into a
// soft corner (issue 21, srfree): two walls 0.01 m thick (E = 50 kPa, nu 0.4, 1000 kg/m^3,
// their outer faces fixed) at zero gap against its +x and +y faces, from 2 mm above the
// slab to 5 mm below the cube's top, each ending 5 mm short of the corner (no wall edge on
// a cube edge); frictionless, gravity (2, 1.5, -9.81) leans it into the corner: the slab's
// normals hold z and the two tilts, the walls' x, y and the yaw. Walls `nw` cells along
// their length and height (one through their thickness). The cube and the walls are moved
// by (ox, oy) in the plane (the slab stays: (0, 0) puts the slab's centre node under the
// cube's bottom diagonal), the walls' tops at z = `top`.
inline Model cube_in_soft_corner(double h, int nw = 4, double ox = 0, double oy = 0, double top = 0.045) {
  const BodySpec slab = damped_slab_spec();
  BodySpec wall = slab;
  mesh::TetMesh s = box_mesh(8, 8, 2, 0.12, 0.12, 0.01);
  mesh::TetMesh wx = box_mesh(1, nw, nw, 0.01, 0.055, top - 0.012), wy = box_mesh(nw, 1, nw, 0.055, 0.01, top - 0.012);
  for (Eigen::Index i = 0; i < wx.X.cols(); ++i) wx.X.col(i) += Vec3(0.08 + ox, 0.02 + oy, 0.012);
  for (Eigen::Index i = 0; i < wy.X.cols(); ++i) wy.X.col(i) += Vec3(0.02 + ox, 0.08 + oy, 0.012);
  BodySpec wall_x = wall, wall_y = wall;
  wall_x.fixed = [ox](const Vec3& p) { return p.x() > 0.09 + ox - 1e-9; };
  wall_y.fixed = [oy](const Vec3& p) { return p.y() > 0.09 + oy - 1e-9; };
  const Vec3 g(2, 1.5, -9.81);
  Model model = make_model({{s, slab, "body"}, {wx, wall_x, "wall_x"}, {wy, wall_y, "wall_y"}}, g, h);
  rigid::RigidState c;
  c.position = Vec3(0.06 + ox, 0.06 + oy, 0.03);
  add_rigid_body(model, "cube", box_shape(Vec3(0.02, 0.02, 0.02)), 500, c);
  enable_rigid_contact(model, {}, {{"body", "cube", 0.0}, {"wall_x", "cube", 0.0}, {"wall_y", "cube", 0.0}}, 1e-3,
                       contact::NcpOptions{});
  return model;
}

// A bar (0.2 x 0.04 x 0.02 m, 800 kg/m^3) hinged about y through its left end's
// mid-height (anchor (0, 0, 0.01)), its right end on a soft pad (0.03 x 0.024 x 0.02 m
// under x in [0.165, 0.195], y in [-0.012, 0.012]; E = 20 kPa, nu 0.3, 1000 kg/m^3,
// damped, bottom fixed), frictionless, margin 1e-3, gravity (0, 0, -9.81), step h
// (validation_rigid_static.cpp explains the pad's placement).
inline Model bar_on_pad(double h) {
  BodySpec spec;
  spec.young = 2e4;
  spec.poisson = 0.3;
  spec.density = 1000;
  spec.rayleigh_mass = 30;
  spec.rayleigh_stiffness = 0.01;
  spec.fixed = [](const Vec3& p) { return p.z() < -0.02 + 1e-9; };
  mesh::TetMesh m = box_mesh(4, 4, 2, 0.03, 0.024, 0.02);
  for (Eigen::Index i = 0; i < m.X.cols(); ++i) m.X.col(i) += Vec3(0.165, -0.012, -0.02);
  Model model = make_model(m, spec, Vec3(0, 0, -9.81), h);
  rigid::RigidState bar;
  bar.position = Vec3(0.1, 0, 0.01);
  add_rigid_body(model, "bar", box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, 0.01, rigid::Joint::Kind::hinge);
  model.rigid[0].joint.anchor = Vec3(0, 0, 0.01);
  model.rigid[0].joint.axis = Vec3::UnitY();
  rigid::initialize(model.rigid[0], bar);
  model.initial.rigid[0] = model.rigid[0].reference;
  enable_rigid_contact(model, {}, {{"body", "bar", 0.0}}, 1e-3, contact::NcpOptions{});
  return model;
}

// The two limited joints of the limits-in-contact tests, appended to `model`: a bar (0.2 x
// 0.04 x 0.02 m, 800 kg/m^3) hinged about y at its left end (anchor (0, 0, 0.01)), limits
// [-0.1, upper], and a block (0.04 m, 500 kg/m^3) on a vertical slider at (1, 0, 0.02),
// limits [0, 0.05]; both surfaces meshed with `max_edge`. Bodies 0 and 1 of the model's
// rigid list (the model has no rigid body before).
inline void add_limited_bar_and_block(Model& model, double upper, double max_edge) {
  rigid::RigidState bar;
  bar.position = Vec3(0.1, 0, 0.01);
  add_rigid_body(model, "bar", box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, max_edge, rigid::Joint::Kind::hinge);
  model.rigid[0].joint.anchor = Vec3(0, 0, 0.01);
  model.rigid[0].joint.axis = Vec3::UnitY();
  model.rigid[0].joint.limits = std::make_pair(-0.1, upper);
  rigid::initialize(model.rigid[0], bar);
  rigid::RigidState block;
  block.position = Vec3(1, 0, 0.02);
  add_rigid_body(model, "block", box_shape(Vec3(0.02, 0.02, 0.02)), 500, block, max_edge,
                 rigid::Joint::Kind::slider);
  model.rigid[1].joint.anchor = block.position;
  model.rigid[1].joint.axis = Vec3::UnitZ();
  model.rigid[1].joint.limits = std::make_pair(0.0, 0.05);
  rigid::initialize(model.rigid[1], block);
}

// BDF2 with a limited joint in contact (rbdlim; integrator/bdf2.cpp): the soft anchor
// (`anchored`, h), the bar of add_limited_bar_and_block alone (hinged about y at its left
// end, limits [-0.1, upper], surface meshed at 0.06) at angle `start` from rest, and the
// sliding wedge (add_sliding_wedge) moved to (0.5, 0.5) on the plane z = 0 ("floor",
// mu 0.3): three sliding contacts keep the NCP running while gravity turns the bar onto
// its upper limit. Bodies: 0 the bar, 1 the wedge. Integrator BDF2, NCP `ncp`.
// rigid_only: without the soft anchor (rigid_only_model: a scene of rigid bodies only).
inline Model bar_onto_its_limit_beside_a_wedge(double h, double start, double upper, const contact::NcpOptions& ncp,
                                               bool rigid_only = false) {
  Model model = rigid_only ? rigid_only_model(h) : anchored(h);
  rigid::RigidState bar;
  bar.position = Vec3(0.1, 0, 0.01);
  add_rigid_body(model, "bar", box_shape(Vec3(0.1, 0.02, 0.01)), 800, bar, 0.06, rigid::Joint::Kind::hinge);
  model.rigid[0].joint.anchor = Vec3(0, 0, 0.01);
  model.rigid[0].joint.axis = Vec3::UnitY();
  model.rigid[0].joint.limits = std::make_pair(-0.1, upper);
  rigid::initialize(model.rigid[0], bar);
  rigid::move_along_joint(model.rigid[0], model.rigid[0].reference, start, 1.0, model.initial.rigid[0]);
  model.initial.rigid[0].velocity.setZero();
  model.initial.rigid[0].angular_velocity.setZero();
  add_sliding_wedge(model);
  model.initial.rigid[1].position += Vec3(0.5, 0.5, 0);
  enable_rigid_contact(model, {plane(Vec3::UnitZ(), 0, "floor")}, {{"wedge", "floor", 0.3}}, 1e-3, ncp);
  model.step.integrator = IntegratorKind::bdf2;
  return model;
}

// A box of nx x ny x nz cells of size (lx, ly, lz) (test::box_mesh) as MSH 2.2 text.
inline std::string box_msh_text(int nx, int ny, int nz, double lx, double ly, double lz) {
  const auto m = box_mesh(nx, ny, nz, lx, ly, lz);
  std::string s = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n" + std::to_string(m.X.cols()) + "\n";
  char buf[128];
  for (int i = 0; i < m.X.cols(); ++i) {
    std::snprintf(buf, sizeof buf, "%d %.17g %.17g %.17g\n", i + 1, m.X(0, i), m.X(1, i), m.X(2, i));
    s += buf;
  }
  s += "$EndNodes\n$Elements\n" + std::to_string(m.tets.cols()) + "\n";
  for (int e = 0; e < m.tets.cols(); ++e) {
    std::snprintf(buf, sizeof buf, "%d 4 2 1 1 %d %d %d %d\n", e + 1, m.tets(0, e) + 1, m.tets(1, e) + 1,
                  m.tets(2, e) + 1, m.tets(3, e) + 1);
    s += buf;
  }
  return s + "$EndElements\n";
}

// The model of the scene `text` (YAML), written with `files` (name, contents: meshes the
// scene names) to SOFTDIFF_TEST_DATA_DIR/<tag>_<pid>/<name>/ and removed after loading.
inline Model load_scene_text(const std::string& tag, const std::string& name, const std::string& text,
                             const std::vector<std::pair<std::string, std::string>>& files = {}) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / (tag + "_" + std::to_string(::getpid())) / name;
  fs::remove_all(dir);
  for (const auto& [file, contents] : files) write_text(dir / file, contents);
  write_text(dir / "scene.yaml", text);
  Model model = io::build_model(io::load_scene(dir / "scene.yaml"));
  fs::remove_all(dir);
  return model;
}

// The shipped clamped beam (meshes/beam.msh: 0.2 x 0.02 x 0.02 m, E = 1 MPa, nu = 0.45,
// 1070 kg/m^3) as the first body of a scene of `steps` steps of 0.01 s, with `damping`
// (a body line such as "    damping: {...}\n", or empty) before its clamp.
inline std::string clamped_beam_yaml(int steps, const std::string& damping = "") {
  const std::filesystem::path root = SOFTDIFF_SOURCE_DIR;
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: " +
         std::to_string(steps) +
         "}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " +
         (root / "meshes/beam.msh").string() +
         "\n"
         "    material: {young: 1.0e6, poisson: 0.45, density: 1070}\n" +
         damping + "    fixed: [{group: clamp}]\n";
}

// A soft slab (slab.msh: box_msh_text(4, 4, 1, 0.06, 0.06, 0.01), clamped at its base,
// corotational E 5e4 Pa, damped) with its top layer rigidified (a free part), and a rigid
// 2 cm cube landing on it turned 0.1 rad about z at v (vx, 0, -0.3) m/s, contact at
// tolerance 1e-12. simulation: the simulation block; cube_extra: lines added to the
// cube's entry (a joint); contact_extra: keys added to the contact block (", backend: ...").
inline std::string cube_on_slab_with_part_yaml(const std::string& simulation, double vx = 0.05,
                                               const std::string& cube_extra = "",
                                               const std::string& contact_extra = "") {
  std::ostringstream v;
  v << vx;
  return "softdiff: 1\n"
         "simulation: " + simulation + "\n"
         "bodies:\n"
         "  - name: slab\n"
         "    mesh: slab.msh\n"
         "    material: {law: corotational, young: 5.0e4, poisson: 0.4, density: 1000}\n"
         "    damping: {rayleigh_mass: 20, rayleigh_stiffness: 0.01}\n"
         "    fixed: [{box: [-1, -1, -1, 1, 1, 1.0e-9]}]\n"
         "    rigidify: [{box: [-1, -1, 0.009, 0.016, 1, 1], attach: free}]\n"
         "  - name: cube\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.01, 0.01, 0.01]}\n"
         "    density: 500\n"
         "    position: [0.0375, 0.0375, 0.0203]\n"
         "    orientation: [0.99875026039496628, 0, 0, 0.049979169270678331]\n"
         "    velocity: [" + v.str() + ", 0, -0.3]\n" + cube_extra +
         "contact: {margin: 1.0e-3, tolerance: 1.0e-12, max_iterations: 5000" + contact_extra +
         ", pairs: [[slab, cube, 0.5]]}\n";
}

// A soft slab (slab.msh: box_msh_text(4, 4, 1, 0.06, 0.06, 0.01), E 5e4 Pa, bottom fixed)
// with its top nodes at x <= 0.031 a free part, and a rigid 2 cm cube (500 kg/m^3) on a
// vertical slider, tilted 0.15 rad about (1, 0.7, 0), its lowest corner 0.2 mm above the
// slab's top face at (0.036, 0.027) (that face's nodes: the part's at x 0.03, soft ones at
// x 0.045), frictionless, statically (the static derivatives of a part beside a rigid body,
// rstp: test_rigid_static_derivatives.cpp, test_cli_rigidify.cpp).
inline std::string slab_part_and_slider_cube_yaml() {
  return "softdiff: 1\n"
         "simulation: {integrator: static, gravity: [0, 0, -9.81]}\n"
         "bodies:\n"
         "  - name: slab\n"
         "    mesh: slab.msh\n"
         "    material: {law: corotational, young: 5.0e4, poisson: 0.4, density: 1000}\n"
         "    fixed: [{box: [-1, -1, -1, 1, 1, 1.0e-9]}]\n"
         "    rigidify: [{box: [-1, -1, 0.009, 0.031, 1, 1], attach: free}]\n"
         "  - name: cube\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.01, 0.01, 0.01]}\n"
         "    density: 500\n"
         "    position: [0.02695, 0.03565, 0.0221689]\n"
         "    orientation: [0.9971888181122073, 0.06138480799297822, 0.042969365595084755, 0.0]\n"
         "    joint: {type: slider, axis: [0, 0, 1]}\n"
         "contact: {margin: 1.0e-3, friction: 0.0, pairs: [[slab, cube, 0.0]]}\n";
}

// A 0.1 m soft cube (cube.msh: box_msh_text(3, 3, 3, 0.1, 0.1, 0.1), E 1e5 Pa, nu 0.3,
// 1000 kg/m^3, no fixed node: held by contact alone) on the plane z = 0, its top nodes a
// free part, statically under `gravity` (a YAML list) with friction mu (rstp: the static
// derivatives of a part on a body held by contact alone; test_rigid_static_derivatives.cpp,
// test_cli_rigidify.cpp).
inline std::string held_cube_with_part_yaml(const std::string& gravity, double mu) {
  std::ostringstream m;
  m << mu;
  return "softdiff: 1\n"
         "simulation: {integrator: static, gravity: " + gravity + "}\n"
         "bodies:\n"
         "  - name: cube\n"
         "    mesh: cube.msh\n"
         "    material: {young: 1.0e5, poisson: 0.3, density: 1000}\n"
         "    rigidify: [{box: [-1, -1, 0.099, 1, 1, 1], attach: free}]\n"
         "obstacles: [{name: floor, type: plane, normal: [0, 0, 1], offset: 0}]\n"
         "contact: {friction: " + m.str() + "}\n";
}

// A free box spinning about an axis off its principal axes (0.04 x 0.02 x 0.01 m, 1000
// kg/m^3, at (0.3, 0.1, 0), turned 0.5 rad about x, v (0, 0.1, 0.5) m/s, omega (1, 2, 8)
// rad/s) as a scene's rigid body entry: beside the clamped beam, in no contact.
inline std::string spinner_yaml() {
  return "  - name: spinner\n"
         "    type: rigid\n"
         "    shape: {type: box, half_extents: [0.02, 0.01, 0.005]}\n"
         "    density: 1000\n"
         "    position: [0.3, 0.1, 0]\n"
         "    orientation: [0.9689124217106447, 0.24740395925452294, 0, 0]\n"
         "    velocity: [0, 0.1, 0.5]\n"
         "    angular_velocity: [1, 2, 8]\n";
}

// A 1.3 kg block with a full (non-diagonal) SPD inertia, so that every component of a
// derivative matters, on a joint of the given kind (its axis and anchor the defaults).
inline rigid::RigidBody rigid_block(rigid::Joint::Kind kind) {
  rigid::RigidBody b;
  b.name = "block";
  b.mass = 1.3;
  b.inertia << 0.021, 0.002, -0.001, 0.002, 0.034, 0.003, -0.001, 0.003, 0.047;
  b.joint.kind = kind;
  return b;
}

// A generic rigid state: off the origin, rotated about a generic axis, moving and spinning
// mostly about z (a gyroscopic term).
inline rigid::RigidState generic_state() {
  rigid::RigidState s;
  s.position = Vec3(0.1, 0.2, 0.3);
  s.orientation = Eigen::Quaterniond(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  s.velocity = Vec3(0.3, -0.2, 0.1);
  s.angular_velocity = Vec3(1, 2, 10);
  return s;
}

// The adjoint of l = a . x_T + b . v_T (soft rows) + c . (the rigid bodies' 12-tangents of
// the final state), with a, b, c drawn from N(rng) in that order, against the forward
// sensitivities dx, dv of the same theta (one column each): its theta gradient is
// a^T dx + b^T dv + the rigid rows'. The reverse sweep recomputes the run bit for bit;
// the gradients agree to 1e-9 of the largest.
inline void expect_adjoint_matches_forward(const Model& model, long T, const diff::ThetaLayout& theta, const MatX& dx,
                                           const MatX& dv, std::mt19937& rng, std::normal_distribution<double>& N) {
  const Eigen::Index n3 = 3L * model.fem.num_nodes, R = static_cast<Eigen::Index>(model.rigid.size());
  const VecX a = VecX::NullaryExpr(n3, [&] { return N(rng); }), b = VecX::NullaryExpr(n3, [&] { return N(rng); });
  const VecX cr = VecX::NullaryExpr(12 * R, [&] { return N(rng); });
  diff::Tape tape;
  Data data(model);
  ASSERT_TRUE(diff::record(model, data, model.initial, T, tape).ok());
  diff::AdjointResult result;
  ASSERT_TRUE(diff::adjoint(
                  model, data, tape, theta,
                  [&](long k, const State&, VecX& bx, VecX& bv) {
                    if (k == T) bx += a, bv += b;
                  },
                  result,
                  [&](long k, const State&, VecX& br) {
                    if (k == T) br += cr;
                  })
                  .ok());
  EXPECT_EQ(result.recompute_mismatch, 0.0);
  VecX expected(dx.cols());
  for (Eigen::Index c = 0; c < dx.cols(); ++c) {
    expected[c] = a.dot(dx.col(c).head(n3)) + b.dot(dv.col(c).head(n3));
    for (Eigen::Index r = 0; r < R; ++r)
      expected[c] += cr.segment<6>(12 * r).dot(dx.col(c).segment<6>(n3 + 6 * r)) +
                     cr.segment<6>(12 * r + 6).dot(dv.col(c).segment<6>(n3 + 6 * r));
  }
  std::cout << "adjoint " << result.theta.transpose() << " against forward " << expected.transpose() << "\n";
  for (Eigen::Index c = 0; c < dx.cols(); ++c)
    EXPECT_NEAR(result.theta[c], expected[c], 1e-9 * expected.cwiseAbs().maxCoeff());
}

}  // namespace softdiff::test::rigid_scenes
