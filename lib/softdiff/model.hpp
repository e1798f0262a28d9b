#pragma once
// Model / State: the aggregate of every stage's constant part, and the state of a
// frame. See data.hpp for the per-step workspace and record.
#include <softdiff/actuation/actuation_model.hpp>
#include <softdiff/collision/contact_derivatives.hpp>
#include <softdiff/collision/detection.hpp>
#include <softdiff/contact/ncp.hpp>
#include <softdiff/core/types.hpp>
#include <softdiff/fem/fem_model.hpp>
#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/integrator/rigidify.hpp>
#include <softdiff/rigid/rigid_body.hpp>

#include <string>
#include <vector>

namespace softdiff {

// bdf2: x_{n+1} = 4/3 x_n - 1/3 x_{n-1} + 2/3 h v_{n+1}, its first step implicit Euler
// (integrator/bdf2.hpp).
enum class IntegratorKind { implicit_euler, static_equilibrium, bdf2 };

// Friction in the static solver (scene.md `static.friction`; docs/method.md "Static
// equilibrium with contact", *Load-step-anchored friction*, 2026-12-04, branch sfric):
// iterate: each Newton iteration's NCP sees the tangential increment H_T dx alone (the
// stick point is wherever the iterations left it: the answer depends on the solver's
// path); load_step: it sees the slip accumulated since the load step began,
// H_T (x_k - x_start) + H_T dx (Coulomb's law on the load step's total slip: one
// implicit step without inertia; the equilibrium a function of the parameters and the
// start state).
enum class StaticFriction { iterate, load_step };

struct StepSettings {
  IntegratorKind integrator = IntegratorKind::implicit_euler;
  double dt = 0.01;                 // h
  long steps = 0;                   // number of steps (implicit_euler)
  Vec3 gravity{0, 0, -9.81};
  int newton_iterations = 1;        // 1: the paper's linearized step; > 1: at most this many Newton solves
  double newton_tolerance = 1e-10;  // relative residual of the implicit Euler equations (newton_iterations > 1)
  int static_max_iterations = 50;   // Newton iterations per load step
  double static_tolerance = 1e-10;  // relative residual force norm (the residual criterion)
  // The answer criterion (method.md "Static equilibrium"), on when
  // static_displacement_tolerance > 0: a load step also ends when the change of the
  // answer still to come (|dx_k| rho / (1 - rho), rho the observed contraction of the
  // Newton increments) is below static_displacement_tolerance of the displacement and
  // the residual below static_residual_tolerance of its reference. io::build_model sets
  // them from the scene (defaults 1e-4 and 1e-3); a Model built in code keeps 0 (the
  // residual criterion alone).
  double static_displacement_tolerance = 0;
  double static_residual_tolerance = 0;
  int static_load_steps = 1;
  StaticFriction static_friction = StaticFriction::iterate;
  double divergence_factor = 100;   // a node further than this many body diagonals from rest: diverged
};

// Exactly what a frame of the output holds; enough to restart.
struct State {
  double t = 0;
  VecX x;  // (3n) positions, node-major
  VecX v;  // (3n) velocities
  std::vector<rigid::RigidState> rigid;  // one per Model::rigid body (pose and velocities)
};

// Contact (scene.md `contact`): collision detection and the NCP solver settings.
// Disabled: no detection, no Delassus, nothing of the contact stage runs.
struct ContactSettings {
  bool enabled = false;
  collision::DetectionModel detection;  // surfaces, obstacles, pair rules, margin, names
  contact::NcpOptions ncp;
  // Randomized smoothing of the collision-detection derivatives where the active
  // feature pair is not unique (collision/contact_derivatives.hpp); sigma is resolved
  // from the scene (default: a tenth of the detection margin).
  collision::SmoothingOptions smoothing;
  // Rigid bodies in contact (docs/method.md "Rigid bodies in contact"): each rigid
  // body's surface vertices are pseudo-nodes numbered after the soft nodes (detection
  // runs on the extended positions); rigid_node_begin[r] is body r's first pseudo-node,
  // rigid_node_body[k - n] the body of pseudo-node k (n soft nodes). Empty without
  // rigid bodies (or without contact).
  std::vector<int> rigid_node_begin;
  std::vector<int> rigid_node_body;
  // A rigid body's resting manifold on a planar obstacle face reduced to the points that
  // can carry force (contact/rigid_contact.hpp reduce_rigid_manifolds): exact, on by
  // default; off only to compare (tests).
  bool reduce_rigid_manifolds = true;
  bool with_rigid() const { return !rigid_node_begin.empty(); }
};

struct Model {
  std::string name;
  fem::FemModel fem;
  actuation::ActuationModel actuation;  // actuators (values over time) and effectors
  StepSettings step;
  integrator::SolverOptions solver;
  ContactSettings contact;
  // Rigid bodies (issue 21, scene.md `type: rigid`), in scene order: each its own
  // 6-DoF system, stepped by rigid::step; with contact, they enter the contact stage's
  // NCP with the soft bodies (contact/rigid_contact.hpp).
  std::vector<rigid::RigidBody> rigid;
  // Rigidified parts of soft bodies (issue 21 item 2, scene.md `rigidify`): free or
  // servo-attached parts, stepped by the reduced mapping of integrator/rigidify.hpp.
  // Empty (the default): nothing of it runs.
  integrator::RigidifyModel rigidify;
  State initial;  // x = rest positions, v = initial velocities (0 on fixed dofs); rigid: the scene's

  // True when the system matrix A does not depend on the state: every body uses
  // the `linear` law (constant K; h is constant). Then K is assembled and A
  // factorized once per run, and f_int = -K (x - X) is a product with the stored K.
  bool constant_system_matrix() const {
    if (fem.bodies.empty()) return false;
    for (const auto& b : fem.bodies)
      if (b.law != material::Law::linear || b.psd_projection) return false;
    return true;
  }
};

}  // namespace softdiff
