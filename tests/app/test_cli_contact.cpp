// `softdiff simulate` with contact: the /contact/* and /solver/contact_* datasets of
// output.md, --strict on a contact solve that misses its tolerance, and bad contact
// input (obstacles, pairs, obstacle meshes): exit 2, a message naming the place and
// the cause, and no output file.
#include <support/cli.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_contact";

// The shipped beam (0.2 x 0.02 x 0.02 m, from the origin) 0.5 mm above a plane,
// falling onto it.
std::string scene(const std::string& obstacles, const std::string& contact, int steps = 20) {
  return "softdiff: 1\n"
         "simulation: {dt: 0.005, steps: " + std::to_string(steps) + "}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    translate: [0, 0, 0.0005]\n"
         "    material: {law: corotational, young: 1.0e5, poisson: 0.3, density: 1000}\n"
         "obstacles:\n" + obstacles + "contact:\n" + contact;
}
const std::string kPlane = "  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0}\n";

std::vector<hsize_t> dims(hid_t file, const char* path) {
  const hid_t d = H5Dopen2(file, path, H5P_DEFAULT);
  EXPECT_GE(d, 0) << path;
  if (d < 0) return {};
  const hid_t s = H5Dget_space(d);
  std::vector<hsize_t> out(static_cast<std::size_t>(H5Sget_simple_extent_ndims(s)));
  H5Sget_simple_extent_dims(s, out.data(), nullptr);
  H5Sclose(s);
  H5Dclose(d);
  return out;
}

template <class T>
std::vector<T> read_all(hid_t file, const char* path, hid_t type) {
  std::size_t n = 1;
  for (hsize_t d : dims(file, path)) n *= d;
  std::vector<T> v(n);
  const hid_t d = H5Dopen2(file, path, H5P_DEFAULT);
  if (n > 0) {
    EXPECT_GE(H5Dread(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()), 0) << path;
  }
  H5Dclose(d);
  return v;
}

TEST(CliContact, WritesContactDatasets) {
  const auto dir = fresh_dir(kWork, "datasets");
  write_text(dir / "scene.yaml", scene(kPlane, "  friction: 0.5\n  margin: 0.001\n"));
  const CliRun r = run_cli("simulate scene.yaml -o out.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"contact\""), std::string::npos) << r.out;
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto offsets = read_all<std::int64_t>(f, "/contact/offsets", H5T_NATIVE_INT64);
  ASSERT_EQ(offsets.size(), 22u);  // T + 1 with T = 21 frames
  EXPECT_EQ(offsets[0], 0);
  EXPECT_EQ(offsets[1], 0);  // frame 0 has no contacts
  for (std::size_t k = 1; k < offsets.size(); ++k) EXPECT_GE(offsets[k], offsets[k - 1]);
  const auto nc = static_cast<hsize_t>(offsets.back());
  EXPECT_GT(nc, 0u);
  EXPECT_EQ(dims(f, "/contact/point"), (std::vector<hsize_t>{nc, 3}));
  EXPECT_EQ(dims(f, "/contact/frame"), (std::vector<hsize_t>{nc, 3, 3}));
  EXPECT_EQ(dims(f, "/contact/force"), (std::vector<hsize_t>{nc, 3}));
  EXPECT_EQ(dims(f, "/contact/mode"), (std::vector<hsize_t>{nc}));
  EXPECT_EQ(dims(f, "/contact/pair"), (std::vector<hsize_t>{nc, 2}));
  EXPECT_EQ(dims(f, "/solver/contact_iterations"), (std::vector<hsize_t>{21}));
  EXPECT_EQ(dims(f, "/solver/contact_residual"), (std::vector<hsize_t>{21}));
  for (auto m : read_all<std::int8_t>(f, "/contact/mode", H5T_NATIVE_INT8)) EXPECT_TRUE(m >= 0 && m <= 2);
  const auto pairs = read_all<std::int32_t>(f, "/contact/pair", H5T_NATIVE_INT32);
  for (std::size_t k = 0; k < pairs.size(); k += 2) {
    EXPECT_EQ(pairs[k], 0);      // beam
    EXPECT_EQ(pairs[k + 1], 1);  // floor
  }
  // Frames: columns (t1, t2, n) with n = +z for the floor; the normal force carries
  // the beam: lambda_n >= 0 and, summed over the last frame, about its weight.
  const auto frames = read_all<double>(f, "/contact/frame", H5T_NATIVE_DOUBLE);
  for (std::size_t k = 0; k < frames.size(); k += 9) EXPECT_NEAR(frames[k + 8], 1.0, 1e-12);  // row z, column n
  const auto forces = read_all<double>(f, "/contact/force", H5T_NATIVE_DOUBLE);
  for (std::size_t k = 0; k < forces.size(); k += 3) EXPECT_GE(forces[k + 2], 0.0);
  {
    const hid_t d = H5Dopen2(f, "/contact/names", H5P_DEFAULT);
    ASSERT_GE(d, 0);
    const hid_t t = H5Dget_type(d);
    std::vector<char*> names(2);
    ASSERT_EQ(dims(f, "/contact/names"), (std::vector<hsize_t>{2}));
    const hid_t mt = H5Tcopy(H5T_C_S1);
    H5Tset_size(mt, H5T_VARIABLE);
    H5Tset_cset(mt, H5T_CSET_UTF8);  // as written (output.md: UTF-8); HDF5 does not convert character sets
    ASSERT_GE(H5Dread(d, mt, H5S_ALL, H5S_ALL, H5P_DEFAULT, names.data()), 0);
    EXPECT_STREQ(names[0], "beam");
    EXPECT_STREQ(names[1], "floor");
    const hid_t s = H5Dget_space(d);
    H5Dvlen_reclaim(mt, s, H5P_DEFAULT, names.data());
    H5Sclose(s);
    H5Tclose(mt);
    H5Tclose(t);
    H5Dclose(d);
  }
  H5Fclose(f);
}

// A contact solve that cannot reach its tolerance in one iteration: a warning and
// exit 0 by default; with --strict an error naming the step and the residuals,
// exit 1, and the frames up to it kept (status "diverged: ...").
// The beam pressed 0.1 mm into the plane (resting on it), 2 steps.
std::string pressed_scene(const std::string& contact) {
  std::string text = scene(kPlane, contact, 2);
  text.replace(text.find("translate: [0, 0, 0.0005]"), 25, "translate: [0, 0, -0.0001]");
  return text;
}

TEST(CliContact, CheckGradThroughContact) {
  // The beam pressed 0.1 mm into the plane, resting and sticking (mu = 0.5), 2 steps:
  // the derivatives through the contact forces (collision detection, the NCP with
  // modes fixed, the corrected step) against differences of whole runs.
  const auto dir = fresh_dir(kWork, "check_grad");
  write_text(dir / "scene.yaml", pressed_scene("  friction: 0.5\n  tolerance: 1.0e-13\n  max_iterations: 20000\n"));
  const CliRun r = run_cli("check-grad scene.yaml --steps 2 --wrt young,friction,x0 --directions 2", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  for (const char* block : {"young", "friction", "x0"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << r.out;
}

TEST(CliContact, JacobianThroughContactReportsTheNcpDerivativesFigures) {
  // The resting beam's vertex contacts are on distinct nodes: a full-rank NCP
  // derivative at every step, every contact geometry differentiable.
  const auto dir = fresh_dir(kWork, "jacobian");
  write_text(dir / "scene.yaml", pressed_scene("  friction: 0.5\n"));
  const CliRun r = run_cli("simulate scene.yaml -o o.h5 --jacobian young,friction --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"derivatives\":{\"ncp_rank_deficient_steps\":0,\"ncp_rank_deficiency_max\":0,"
                       "\"nondifferentiable_contacts\":0,\"smoothed_contacts\":0}"),
            std::string::npos)
      << r.out;
  const hid_t f = H5Fopen((dir / "o.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  EXPECT_EQ(dims(f, "/jacobians/friction").size(), 2u);
  H5Fclose(f);
}

TEST(CliContact, StrictMakesAnUnconvergedContactSolveAnError) {
  const auto dir = fresh_dir(kWork, "strict");
  write_text(dir / "scene.yaml",
             scene(kPlane, "  friction: 0.5\n  max_iterations: 1\n  tolerance: 1.0e-12\n  polish: false\n"));
  CliRun r = run_cli("simulate scene.yaml -o lenient.h5", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("contact solver did not converge"), std::string::npos) << r.err;
  r = run_cli("simulate scene.yaml -o strict.h5 --strict", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("contact solver did not converge"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("residuals primal"), std::string::npos) << r.err;
  EXPECT_TRUE(fs::exists(dir / "strict.h5"));
}

// Newton (newton_iterations > 1) with contact (docs/method.md "Newton iterations with
// contact"): the falling beam with newton_iterations 4 runs, every step reaches
// newton_tolerance (--strict), and the /contact datasets are written with the forces
// carrying the beam; check-grad through contact and Newton (the implicit function
// theorem at the converged step) against differences of whole runs.
std::string with_newton(std::string text, const std::string& settings) {
  const auto at = text.find("}", text.find("steps: "));
  text.insert(at, settings);
  return text;
}

TEST(CliContact, NewtonWithContactWritesContactDatasets) {
  const auto dir = fresh_dir(kWork, "newton");
  write_text(dir / "scene.yaml", with_newton(scene(kPlane, "  friction: 0.5\n  margin: 0.001\n"), ", newton_iterations: 4"));
  const CliRun r = run_cli("simulate scene.yaml -o out.h5 --json --strict", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"newton_not_converged_steps\":0"), std::string::npos) << r.out;
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto offsets = read_all<std::int64_t>(f, "/contact/offsets", H5T_NATIVE_INT64);
  ASSERT_EQ(offsets.size(), 22u);
  const auto nc = static_cast<hsize_t>(offsets.back());
  EXPECT_GT(nc, 0u);
  EXPECT_EQ(dims(f, "/contact/force"), (std::vector<hsize_t>{nc, 3}));
  EXPECT_EQ(dims(f, "/contact/mode"), (std::vector<hsize_t>{nc}));
  const auto forces = read_all<double>(f, "/contact/force", H5T_NATIVE_DOUBLE);
  double last_frame_normal = 0;
  for (std::size_t k = 0; k < forces.size(); k += 3) {
    EXPECT_GE(forces[k + 2], 0.0);
    if (static_cast<std::int64_t>(k / 3) >= offsets[20]) last_frame_normal += forces[k + 2];
  }
  EXPECT_GT(last_frame_normal, 0.0);
  H5Fclose(f);
}

// Newton converged to 1e-12 (30 iterations at most), so that the differences see the
// converged map. --eps 1e-5: at check-grad's default 1e-4 the x0 block's differences
// are off by 7e-2 relative, at 1e-5 by 1.8e-7 and at 1e-6 by 1.8e-6 (measured): not
// the h^2 of truncation, the runs at +-1e-4 along direction 0 cross a contact event.
TEST(CliContact, CheckGradThroughContactWithNewton) {
  const auto dir = fresh_dir(kWork, "check_grad_newton");
  write_text(dir / "scene.yaml", with_newton(pressed_scene("  friction: 0.5\n  tolerance: 1.0e-13\n  max_iterations: 20000\n"),
                                             ", newton_iterations: 30, newton_tolerance: 1.0e-12"));
  const CliRun r = run_cli("check-grad scene.yaml --steps 2 --wrt young,friction,x0 --directions 2 --eps 1e-5", dir);
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.out.find("ABOVE TOLERANCE"), std::string::npos) << r.out;
  for (const char* block : {"young", "friction", "x0"})
    EXPECT_NE(r.out.find(std::string("\n") + block + " "), std::string::npos) << r.out;
}

struct BadContact {
  std::string name;
  std::string obstacles, contact;
  std::vector<std::string> expect;
  std::string extra_file = {}, extra_text = {};  // written into the case's folder
};
void PrintTo(const BadContact& b, std::ostream* os) { *os << b.name; }

class CliContactBadInput : public ::testing::TestWithParam<BadContact> {};

TEST_P(CliContactBadInput, ExitsTwoWithMessageAndNoOutput) {
  const auto& p = GetParam();
  const auto dir = fresh_dir(kWork, p.name);
  if (!p.extra_file.empty()) write_text(dir / p.extra_file, p.extra_text);
  write_text(dir / "scene.yaml", scene(p.obstacles, p.contact));
  for (const std::string command : {"simulate scene.yaml -o o.h5", "info scene.yaml"}) {
    SCOPED_TRACE(command);
    const CliRun r = run_cli(command, dir);
    EXPECT_EQ(r.code, 2) << r.err;
    for (const auto& e : p.expect) EXPECT_NE(r.err.find(e), std::string::npos) << "missing '" << e << "' in: " << r.err;
    for (const auto& entry : fs::directory_iterator(dir)) {
      const auto ext = entry.path().extension();
      EXPECT_TRUE(ext != ".h5" && ext != ".xmf" && ext != ".partial") << "left behind: " << entry.path();
    }
  }
}

// An open surface: one triangle.
const char* kOpenStl = "solid open\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\n"
                       "endfacet\nendsolid open\n";

INSTANTIATE_TEST_SUITE_P(
    Cases, CliContactBadInput,
    ::testing::Values(
        BadContact{"unknown_pair", kPlane, "  pairs: [[beam, flor, 0.3]]\n", {"scene.yaml:", "contact.pairs[0][1]", "unknown body or obstacle 'flor'"}},
        BadContact{"negative_mu", kPlane, "  friction: -1\n", {"scene.yaml:", "contact.friction", "must be >= 0"}},
        BadContact{"obstacle_mesh_missing", "  - {name: key, type: mesh, mesh: nokey.stl}\n", "  friction: 0.3\n",
                   {"scene.yaml:", "obstacles[0].mesh", "mesh file not found"}},
        BadContact{"obstacle_mesh_open", "  - {name: key, type: mesh, mesh: open.stl}\n", "  friction: 0.3\n",
                   {"scene.yaml:", "obstacles[0]", "open.stl"}, "open.stl", kOpenStl},
        BadContact{"obstacle_mesh_garbage", "  - {name: key, type: mesh, mesh: junk.stl}\n", "  friction: 0.3\n",
                   {"scene.yaml:", "obstacles[0]", "junk.stl"}, "junk.stl", "this is not an STL file\n"},
        BadContact{"obstacle_missing_key", "  - {name: ball, type: sphere, center: [0, 0, 0]}\n", "  friction: 0.3\n",
                   {"scene.yaml:", "obstacles[0]", "needs 'radius'"}}),
    [](const auto& p) { return p.param.name; });

}  // namespace
