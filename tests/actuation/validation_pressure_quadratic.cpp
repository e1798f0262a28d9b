// Validation of the quadratic cavity (issue 18): the volume enclosed by 6-node
// triangles on a curved surface against the analytic volume.
//
// The hollow sphere octant of validation_pressure.cpp (tests/data/hollow_sphere_octant.geo:
// a = 10 mm, b = 20 mm), meshed by gmsh at order 2 (mid-edge nodes on the spheres)
// and at order 1, at h = 5, 2.5 and 1.25 mm. Its whole boundary (the two spherical
// surfaces and the three planes: closed) taken as a cavity is oriented into the solid
// and encloses V = -pi (b^3 - a^3) / 6. The surface integral itself is exact for the
// quadratic surface (test_quadratic_actuators.cpp), so the error is that of the
// geometry: the quadratic interpolation of a sphere (O(h^3) in position) against the
// flat triangles' O(h^2). Measured (gmsh 4.x of Debian): 6-node volume errors 1.2e-7,
// 2.2e-6, 2.5e-7 at h = 5, 2.5, 1.25 mm (at 5 mm the inner and outer spheres' errors,
// of opposite signs, nearly cancel), 3-node 1.4e-2, 3.5e-3, 7.6e-4; observed order
// between the two finer sizes 3.1 (6-node) and 2.2 (3-node). Checked: the quadratic
// error is below a tenth of the linear one at every size, and its observed order
// between the two finer sizes exceeds 2.5 (the linear surface's is 2). The figures are
// printed. dV/dx: sum_i H_a[i] . x_i = 3 V (V is homogeneous of degree 3 in x and
// H_a = dV/dx exactly: Euler's identity), to round-off.
#include <softdiff/actuation/pressure.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <string>

namespace pressure_quadratic_test {

using namespace softdiff;
namespace fs = std::filesystem;

constexpr double kA = 0.01, kB = 0.02;

fs::path scratch() {
  static const fs::path dir = [] {
    const fs::path d = fs::path(SOFTDIFF_TEST_DATA_DIR) / ("pressure_quadratic_" + std::to_string(::getpid()));
    fs::remove_all(d);
    fs::create_directories(d);
    return d;
  }();
  return dir;
}

// The octant meshed at size h and element order `order`; empty on failure (with the log).
fs::path mesh(double h, int order, std::string& failure) {
  std::ifstream in(fs::path(SOFTDIFF_SOURCE_DIR) / "tests/data/hollow_sphere_octant.geo");
  std::string text(std::istreambuf_iterator<char>(in), {});
  const std::string from = "Mesh.ElementOrder = 1;";
  const auto at = text.find(from);
  if (at == std::string::npos) {
    failure = "hollow_sphere_octant.geo no longer sets Mesh.ElementOrder = 1";
    return {};
  }
  text.replace(at, from.size(), "Mesh.ElementOrder = " + std::to_string(order) + ";");
  const std::string tag = std::to_string(order) + "_" + std::to_string(static_cast<int>(std::lround(h * 1e5)));
  const fs::path geo = scratch() / ("octant_" + tag + ".geo"), out = scratch() / ("octant_" + tag + ".msh");
  std::ofstream(geo) << text;
  const fs::path log = scratch() / "gmsh.log";
  char size[32];
  std::snprintf(size, sizeof size, "%.17g", h);
  const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" -3 \"" + geo.string() + "\" -setnumber h " + size +
                          " -format msh41 -o \"" + out.string() + "\" > \"" + log.string() + "\" 2>&1";
  if (std::system(cmd.c_str()) != 0 || !fs::exists(out)) {
    std::ifstream l(log);
    failure = cmd + "\n" + std::string(std::istreambuf_iterator<char>(l), {});
    return {};
  }
  return out;
}

struct Result {
  double error = 0;       // |V / V_exact - 1|
  double euler = 0;       // |H . x - 3 V| / |3 V|
  int triangles = 0;
};

Result cavity_volume(const fs::path& file) {
  const mesh::TetMesh m = io::read_gmsh(file);
  const Triangles tris = mesh::boundary_triangles(m.tets);
  const mesh::Triangles6 tris6 = m.order == 2 ? mesh::quadratic_triangles(m, tris) : mesh::Triangles6();
  actuation::Cavity c;
  const auto st = actuation::Cavity::create(m.X, m.tets, tris, 0, c, m.order == 2 ? &tris6 : nullptr);
  EXPECT_TRUE(st.ok()) << st.message();
  EXPECT_TRUE(c.closed());
  const VecX x = Eigen::Map<const VecX>(m.X.data(), m.X.size());
  const double V = c.volume(x), exact = -std::numbers::pi * (kB * kB * kB - kA * kA * kA) / 6;
  VecX H(x.size());
  c.gradient(x, H);
  Result r;
  r.error = std::abs(V / exact - 1);
  r.euler = std::abs(H.dot(x) - 3 * V) / std::abs(3 * V);
  r.triangles = c.num_triangles();
  return r;
}

TEST(PressureQuadraticValidation, CurvedOctantVolumeConvergesAtAHighOrder) {
  const double sizes[3] = {0.005, 0.0025, 0.00125};
  Result p1[3], p2[3];
  for (int k = 0; k < 3; ++k) {
    std::string failure;
    const fs::path f1 = mesh(sizes[k], 1, failure), f2 = mesh(sizes[k], 2, failure);
    ASSERT_TRUE(failure.empty()) << failure;
    p1[k] = cavity_volume(f1);
    p2[k] = cavity_volume(f2);
    std::printf("h = %.2f mm: %d boundary triangles; volume error: 3-node %.3e, 6-node %.3e; |H.x - 3V|/|3V| %.1e\n",
                1e3 * sizes[k], p2[k].triangles, p1[k].error, p2[k].error, p2[k].euler);
    EXPECT_LT(p2[k].error, 0.1 * p1[k].error);
    EXPECT_LT(p2[k].euler, 1e-13);
  }
  const double order2 = std::log2(p2[1].error / p2[2].error), order1 = std::log2(p1[1].error / p1[2].error);
  std::printf("observed order (2.5 -> 1.25 mm): 3-node %.2f, 6-node %.2f\n", order1, order2);
  EXPECT_GT(order2, 2.5);
  EXPECT_LT(order1, 2.5);
}

}  // namespace pressure_quadratic_test
