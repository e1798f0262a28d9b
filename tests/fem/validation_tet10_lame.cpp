// Validation of the quadratic tetrahedron against Lamé's thick cylinder (analytic).
//
// A quarter of a ring, inner radius a = 10 mm, outer b = 20 mm, 2.5 mm thick in z,
// linear law, E = 1 MPa. Plane strain: u_z = 0 at every node; symmetry: u_y = 0 on
// y = 0 and u_x = 0 on x = 0. The load is a prescribed radial displacement delta of
// the inner surface (softdiff's pressure cavities are not yet available on quadratic
// bodies; the internal pressure that holds it is checked through the reactions), the
// outer surface is free. The linear solution is u_r = A r + B / r with
//   sigma_rr(b) = 0:  A = mu B / ((lambda + mu) b^2),   u_r(a) = delta:  B = delta / (a A/B + 1/a),
// and the internal pressure p = -sigma_rr(a) = 2 mu B (1/a^2 - 1/b^2), i.e. the inner
// nodes' reactions sum to a total radial force p a (pi/2) t_z on the quarter.
//
// The mesh is a structured box in (s, theta, z), each box split into 6 tets, elevated
// to 10-node tets in parameter space and then mapped (r = a + (b - a) s, x = r cos theta,
// y = r sin theta): every node, the mid-edge ones included, lies on the exact
// geometry, so the curved boundaries are represented to second order (isoparametric).
// 4-node tets on the same vertices (a polygonal ring) are run for contrast.
//
// Measured figures (the printout) go to docs/accuracy.md "Quadratic tetrahedra".
#include <softdiff/data.hpp>
#include <softdiff/fem/assembly.hpp>
#include <softdiff/integrator/static_solver.hpp>
#include <support/meshes.hpp>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <gtest/gtest.h>

using namespace softdiff;

namespace tet10_lame {

constexpr double a = 0.01, b = 0.02, tz = 0.0025, E = 1e6, delta = 1e-5;

struct Result {
  double max_error = 0;       // max over nodes of |u - u_exact| / delta
  double outer_error = 0;     // mean u_r over the outer nodes against u_exact(b), relative
  double pressure_error = 0;  // total radial reaction of the inner nodes against p a (pi/2) tz, relative
  int tets = 0;
};

double lame_B(double poisson) {
  const auto lame = material::lame_from_young_poisson(E, poisson);
  const double AB = lame.mu / ((lame.lambda + lame.mu) * b * b);
  return delta / (a * AB + 1 / a);
}

double exact_ur(double r, double poisson) {
  const auto lame = material::lame_from_young_poisson(E, poisson);
  const double B = lame_B(poisson), A = lame.mu * B / ((lame.lambda + lame.mu) * b * b);
  return A * r + B / r;
}

Result solve(int ns, int nt, bool quadratic, double poisson) {
  mesh::TetMesh m = test::box_mesh(ns, nt, 1, 1.0, 1.0, tz);
  if (quadratic) mesh::elevate_to_quadratic(m);
  for (int i = 0; i < m.num_nodes(); ++i) {
    const double r = a + (b - a) * m.X(0, i), th = 0.5 * std::numbers::pi * m.X(1, i);
    m.X.col(i) = Vec3(r * std::cos(th), r * std::sin(th), m.X(2, i));
  }
  const int n = m.num_nodes();
  auto radius = [&](int i) { return std::hypot(m.X(0, i), m.X(1, i)); };
  const double tol = 1e-9 * b;
  fem::BodyModel body;
  body.name = "ring";
  body.mesh = m;
  body.surface = mesh::boundary_triangles(m.tets);
  body.law = material::Law::linear;
  body.young = E;
  body.poisson = poisson;
  body.density = 1000;
  std::vector<unsigned char> fixed(3 * n, 0);
  for (int i = 0; i < n; ++i) {
    fixed[3 * i + 2] = 1;                                // plane strain
    if (std::abs(m.X(1, i)) < tol) fixed[3 * i + 1] = 1;  // y = 0: symmetry
    if (std::abs(m.X(0, i)) < tol) fixed[3 * i + 0] = 1;  // x = 0: symmetry
    if (radius(i) < a + tol) fixed[3 * i] = fixed[3 * i + 1] = 1;  // inner surface: prescribed
  }
  std::vector<fem::BodyModel> bodies{body};
  Model model;
  fem::build_fem_model(std::move(bodies), fixed, Vec3::Zero(), model.fem);
  model.step.gravity = Vec3::Zero();
  model.step.integrator = IntegratorKind::static_equilibrium;
  model.step.static_tolerance = 1e-12;
  model.initial.x = Eigen::Map<const VecX>(model.fem.X.data(), 3 * n);
  model.initial.v = VecX::Zero(3 * n);
  for (int i = 0; i < n; ++i)
    if (radius(i) < a + tol) model.initial.x.segment<2>(3 * i) += delta * m.X.col(i).head<2>() / radius(i);
  Data data(model);
  State out;
  const auto status = integrator::solve_static(model, data, model.initial, out);
  EXPECT_TRUE(status.ok()) << describe(model, status);
  Result res;
  res.tets = model.fem.num_tets;
  double outer_sum = 0, reaction = 0;
  int outer_count = 0;
  for (int i = 0; i < n; ++i) {
    const Vec3 X = model.fem.X.col(i), u = out.x.segment<3>(3 * i) - X;
    const double r = radius(i);
    const Vec3 er(X.x() / r, X.y() / r, 0);
    res.max_error = std::max(res.max_error, (u - exact_ur(r, poisson) * er).norm() / delta);
    if (r > b - tol) {
      outer_sum += u.dot(er);
      ++outer_count;
    }
  }
  // The inner nodes' reactions: the internal forces there (f_int = -dE/dx; the
  // surface's support pushes with -f_int) along e_r.
  fem::FemData fd;
  fd.resize(model.fem);
  EXPECT_TRUE(fem::evaluate(model.fem, out.x, {false, true, false}, fd));
  for (int i = 0; i < n; ++i) {
    const double r = radius(i);
    if (r < a + tol) reaction += -(fd.f_int[3 * i] * model.fem.X(0, i) + fd.f_int[3 * i + 1] * model.fem.X(1, i)) / r;
  }
  const auto lame = material::lame_from_young_poisson(E, poisson);
  const double p = 2 * lame.mu * lame_B(poisson) * (1 / (a * a) - 1 / (b * b));
  const double total = p * a * 0.5 * std::numbers::pi * tz;
  res.outer_error = (outer_sum / outer_count) / exact_ur(b, poisson) - 1;
  res.pressure_error = reaction / total - 1;
  return res;
}

// TET10 on 4 x 8 and 8 x 16 (radial x circumferential) cells of 6 tets: the brief's
// 0.5% for the outer displacement and the pressure on the coarse mesh, and a
// displacement error that shrinks at least 4x when the mesh is halved (order >= 2;
// quadratic elements converge at order 3 in displacement, measured below). The 0.5%
// is the same-mesh agreement goal of issue 18 for this case; the coarse mesh's errors
// are far below it (printed), so the check is not at the edge of the tolerance.
TEST(Tet10Lame, ThickCylinderAgainstAnalytic) {
  const double nu = 0.45;
  const Result coarse = solve(4, 8, true, nu), fine = solve(8, 16, true, nu), linear = solve(8, 16, false, nu);
  std::printf("poisson %.3f, TET10 %d tets: max |u - u_exact| / delta %.3e, outer u_r %+.3e, pressure %+.3e\n", nu,
              coarse.tets, coarse.max_error, coarse.outer_error, coarse.pressure_error);
  std::printf("poisson %.3f, TET10 %d tets: max |u - u_exact| / delta %.3e, outer u_r %+.3e, pressure %+.3e\n", nu,
              fine.tets, fine.max_error, fine.outer_error, fine.pressure_error);
  std::printf("poisson %.3f, TET4  %d tets: max |u - u_exact| / delta %.3e, outer u_r %+.3e, pressure %+.3e\n", nu,
              linear.tets, linear.max_error, linear.outer_error, linear.pressure_error);
  std::printf("TET10 displacement order (max error, 4x8 -> 8x16): %.2f\n",
              std::log(coarse.max_error / fine.max_error) / std::log(2.0));
  EXPECT_LT(std::abs(coarse.outer_error), 5e-3);
  EXPECT_LT(std::abs(coarse.pressure_error), 5e-3);
  EXPECT_LT(coarse.max_error, 5e-3);
  EXPECT_LT(fine.max_error, coarse.max_error / 4);
  EXPECT_LT(std::abs(fine.pressure_error), std::abs(coarse.pressure_error));
  // The linear tets on the same vertices (4x the tets of the coarse TET10 mesh, about
  // the same nodes as it) are less accurate.
  EXPECT_GT(linear.max_error, coarse.max_error);
}

// Near incompressibility (documented in docs/accuracy.md): the same ring at poisson
// 0.49 and 0.499 on the coarse and the fine mesh. The pressure carries lambda div u
// and the displacement error grows with poisson on a fixed mesh (the printout: on
// the coarse mesh at 0.499 the displacement is 1.1% off, beyond the 0.5% of poisson
// 0.45: the locking that remains). What is checked is that it is not a locking
// plateau: both errors fall with the mesh at the order of the locking-free case
// (displacement at least 4x when h halves, as at 0.45) and the 10-node element is
// more accurate than 4-node tets on the same vertices.
TEST(Tet10Lame, NearIncompressibility) {
  for (double nu : {0.49, 0.499}) {
    const Result c = solve(4, 8, true, nu), f = solve(8, 16, true, nu), l = solve(8, 16, false, nu);
    std::printf("poisson %.3f: TET10 %d tets: u %.3e, outer u_r %+.3e, pressure %+.3e; %d tets: u %.3e, "
                "outer u_r %+.3e, pressure %+.3e; TET4 %d tets: u %.3e, outer u_r %+.3e, pressure %+.3e\n",
                nu, c.tets, c.max_error, c.outer_error, c.pressure_error, f.tets, f.max_error, f.outer_error,
                f.pressure_error, l.tets, l.max_error, l.outer_error, l.pressure_error);
    EXPECT_LT(f.max_error, c.max_error / 4) << "poisson " << nu;
    EXPECT_LT(std::abs(f.pressure_error), std::abs(c.pressure_error) / 4) << "poisson " << nu;
    EXPECT_LT(f.max_error, l.max_error) << "poisson " << nu;
    EXPECT_LT(std::abs(f.pressure_error), std::abs(l.pressure_error)) << "poisson " << nu;
  }
}

}  // namespace tet10_lame
