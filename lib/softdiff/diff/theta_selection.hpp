#pragma once
// The theta lists of `simulate --jacobian` and `check-grad --wrt` (docs/cli.md), and of
// the Python module's `jacobian=` (docs/python.md; moved here from app/theta.hpp on
// 2026-12-04 so that both use one parser):
// comma-separated names among young, poisson, density, rayleigh_mass,
// rayleigh_stiffness (one column per body, in body order), actuation (one column per
// actuator: a constant offset of its value), x0, v0 (3 n_total columns each, then 6 per
// rigid body), mass (one column per rigid body) and inertia (six per rigid body: xx, yy,
// zz, xy, xz, yz in body axes), issue 21.
#include <softdiff/diff/trajectory.hpp>
#include <softdiff/model.hpp>

#include <string>
#include <vector>

namespace softdiff::diff {

struct ThetaGroup {
  std::string name;                 // as given: "young", "actuation", "x0", ...
  Eigen::Index offset = 0, size = 0;  // its columns in the layout
  std::vector<std::string> columns;   // a name per column: "young[beam]", "x0[3]" ...
};

struct ThetaSelection {
  ThetaLayout layout;
  std::vector<ThetaGroup> groups;   // in the order given
};

// friction: one column per contact pair rule. Throws InputError (exit 2) for an empty
// list, an unknown or repeated name, friction without contact, `actuation` in a scene without
// actuators, or a scene whose step is not differentiated (newton_iterations > 1 with
// psd_projection; a static scene with psd_projection, a pressure cavity or a rotation
// servo; x0, v0 for a static scene), naming the option.
// parse_theta differentiates rigid bodies with and without contact, joint limits in
// contact included (on the dense contact backend), under implicit_euler and bdf2; it
// refuses (issue 21) limits in contact on contact.backend: sparse.

// The name of row k (0..5) of rigid body `body`'s block of a state's rows (output.md's
// /jacobians rows): "x[key].x" ... "x[key].rz" (position, rotation vector) or
// "v[key].vx" ... "v[key].wz" (velocity, angular velocity); prefix "x0"/"v0" for the
// columns of theta's initial-state groups ("x0[key].rx").
std::string rigid_row_name(const Model& model, int body, int k, bool velocity, const std::string& prefix);

ThetaSelection parse_theta(const std::string& option, const std::string& list, const Model& model);

// The static Jacobian d x*/d theta over `layout`'s columns at the equilibrium
// (integrator::static_sensitivities: parameters, actuation, rigid bodies' mass and
// inertia), as `simulate --jacobian`, `check-grad` and the Python module take it. Returns
// "" or the failure's message: "the derivative of the equilibrium failed" with the
// derivative's own ComputationError (its iterations, contact_step_derivatives.cpp) after a
// colon, or the cause that static_sensitivities reports by returning false.
std::string static_jacobian(const Model& model, Data& data, const State& equilibrium, const ThetaLayout& layout,
                            MatX& dx_dtheta);

}  // namespace softdiff::diff
