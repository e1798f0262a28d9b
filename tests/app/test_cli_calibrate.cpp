// softdiff calibrate (docs/cli.md, docs/output.md /calibration): end to end on the
// shipped beam mesh (clamped, 5 steps of 10 ms, undamped): a target made by `simulate`
// with young = 2e5, then recovered from 5e4 with every frame, from markers (four points
// given at time 0 and followed in the target), the file's /calibration group and the
// iteration lines; a run that stops without converging exits 1 and says so; every kind
// of bad input exits 2 with a message naming the problem and leaves no output file.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <Eigen/Core>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_calibrate";

std::string scene(double young = 2.0e5) {
  char e[32];
  std::snprintf(e, sizeof e, "%.17g", young);
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: 5}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    material: {law: corotational, young: " + e + ", poisson: 0.45, density: 1070}\n"
         "    fixed:\n"
         "      - group: clamp\n";
}

// A folder with scene.yaml and target.h5 (simulated with the truth).
fs::path with_target(const std::string& name) {
  const auto dir = fresh_dir(kWork, name);
  write_text(dir / "scene.yaml", scene());
  const CliRun r = run_cli("simulate scene.yaml -o target.h5 --quiet", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  return dir;
}

double json_number(const std::string& json, const std::string& key) {
  const auto k = json.find("\"" + key + "\":");
  if (k == std::string::npos) return std::nan("");
  return std::strtod(json.c_str() + k + key.size() + 3, nullptr);
}

TEST(CliCalibrate, RecoversYoungFromAllFrames) {
  const auto dir = with_target("young");
  const CliRun r = run_cli("calibrate scene.yaml --param young --init 5e4 --target target.h5 -o cal.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NEAR(json_number(r.out, "young") / 2e5, 1.0, 1e-6) << r.out;
  EXPECT_NE(r.out.find("\"converged\":true"), std::string::npos) << r.out;
  // One line per iteration on stderr: iteration, parameters, cost, |gradient|, damping.
  EXPECT_NE(r.err.find("iteration 0: young = 50000, cost "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("|gradient|"), std::string::npos);
  EXPECT_NE(r.err.find("damping"), std::string::npos);
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen((dir / "cal.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  EXPECT_EQ(h5_string_attribute(f, "/", "status"), "complete");
  const auto dims = h5_shape(f, "/calibration/iterations");
  ASSERT_EQ(dims.size(), 2u);
  EXPECT_EQ(dims[1], 6u);  // iteration, young, cost, gradient norm, damping, seconds
  EXPECT_EQ(h5_string_attribute(f, "/calibration/iterations", "columns"), "iteration,young,cost,gradient_norm,damping,seconds");
  EXPECT_NEAR(h5_number_attribute(f, "/calibration", "young") / 2e5, 1.0, 1e-6);
  EXPECT_EQ(h5_number_attribute(f, "/calibration", "converged"), 1.0);
  EXPECT_EQ(h5_number_attribute(f, "/calibration", "iterations") + 1, static_cast<double>(dims[0]));
  EXPECT_LT(h5_number_attribute(f, "/calibration", "final_cost"), 1e-20);
  // The file holds the scene simulated with the identified value: its frames are the
  // target's.
  const std::vector<double> x = h5_read(f, "/bodies/beam/x");
  H5Fclose(f);
  const hid_t t = H5Fopen((dir / "target.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const std::vector<double> xt = h5_read(t, "/bodies/beam/x");
  H5Fclose(t);
  ASSERT_EQ(x.size(), xt.size());
  double worst = 0;
  for (std::size_t i = 0; i < x.size(); ++i) worst = std::max(worst, std::abs(x[i] - xt[i]));
  EXPECT_LT(worst, 1e-9);
}

TEST(CliCalibrate, RecoversYoungFromMarkers) {
  const auto dir = with_target("markers");
  // Four points of the beam (at rest, time 0), followed in the target: the nodes nearest
  // to them, whose positions the target holds.
  const hid_t f = H5Fopen((dir / "target.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const auto dims = h5_shape(f, "/bodies/beam/x");
  const std::vector<double> x = h5_read(f, "/bodies/beam/x"), time = h5_read(f, "/time");
  H5Fclose(f);
  const std::size_t n = dims[1];
  std::string csv = "time,marker,x,y,z\n";
  const int nodes[4] = {100, 400, 700, 1000};
  for (std::size_t k = 0; k < time.size(); ++k)
    for (int m = 0; m < 4; ++m) {
      const double* p = x.data() + (k * n + static_cast<std::size_t>(nodes[m])) * 3;
      char line[160];
      std::snprintf(line, sizeof line, "%.17g,m%d,%.17g,%.17g,%.17g\n", time[k], m, p[0], p[1], p[2]);
      csv += line;
    }
  write_text(dir / "markers.csv", csv);
  const CliRun r = run_cli("calibrate scene.yaml --param young --init 5e4 --markers markers.csv -o cal.h5 --json", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NEAR(json_number(r.out, "young") / 2e5, 1.0, 1e-6) << r.out;
}

TEST(CliCalibrate, StoppingWithoutConvergenceExitsOne) {
  const auto dir = with_target("not_converged");
  const CliRun r = run_cli("calibrate scene.yaml --param young --init 5e4 --target target.h5 -o cal.h5 --max-iterations 1", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("did not converge after 1 iterations (the maximum number of iterations was reached)"), std::string::npos) << r.err;
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen((dir / "cal.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  EXPECT_EQ(h5_number_attribute(f, "/calibration", "converged"), 0.0);
  H5Fclose(f);
}

TEST(CliCalibrate, ASingleFrameWarns) {
  const auto dir = with_target("single");
  const CliRun r = run_cli("calibrate scene.yaml --param young --init 1.5e5 --target target.h5 --frames last -o cal.h5", dir);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("a single frame as target"), std::string::npos) << r.err;
}

TEST(CliCalibrate, BadInputExitsTwoWithoutOutput) {
  const auto dir = with_target("bad");
  write_text(dir / "not_hdf5.h5", "hello\n");
  write_text(dir / "other.yaml", "softdiff: 1\nsimulation: {dt: 0.01, steps: 5}\nbodies:\n  - name: bar\n    mesh: " +
                                     (kRoot / "meshes/beam.msh").string() +
                                     "\n    material: {law: corotational, young: 2.0e5, poisson: 0.45, density: 1070}\n"
                                     "    fixed:\n      - group: clamp\n");
  ASSERT_EQ(run_cli("simulate other.yaml -o other.h5 --quiet", dir).code, 0);
  write_text(dir / "bad_header.csv", "t,m,x,y,z\n0,a,0,0,0\n");
  write_text(dir / "bad_number.csv", "time,marker,x,y,z\n0,a,0.1,0.01,0.01\n0.01,a,0.1,zero,0.01\n");
  write_text(dir / "bad_fields.csv", "time,marker,x,y,z\n0,a,0.1,0.01\n");
  write_text(dir / "outside.csv", "time,marker,x,y,z\n0,a,0.5,0.5,0.5\n0.01,a,0.5,0.5,0.5\n");
  write_text(dir / "unembedded.csv", "time,marker,x,y,z\n0.01,a,0.1,0.01,0.01\n");
  write_text(dir / "off_step.csv", "time,marker,x,y,z\n0,a,0.1,0.01,0.01\n0.015,a,0.1,0.01,0.01\n");
  write_text(dir / "exists.h5", "x");
  struct Case {
    std::string args, message;
  };
  const Case cases[] = {
      {"--param stiffness --target target.h5", "--param stiffness: unknown parameter 'stiffness'"},
      {"--param rod.young --target target.h5", "--param rod.young: no body 'rod'"},
      {"--param young,young --target target.h5", "'young' is listed twice"},
      {"--param friction --target target.h5", "'friction' needs contact"},
      {"--param young --init 1,2 --target target.h5", "--init 1,2: expected 1 values"},
      {"--param young --init abc --target target.h5", "--init abc: 'abc' is not a number"},
      {"--param poisson --init 0.7 --target target.h5", "--init: poisson = 0.7 is outside the calibrated range"},
      {"--param young --init -5 --target target.h5", "--init: young = -5 is outside the calibrated range"},
      {"--param young", "give the observations with --target"},
      {"--param young --target missing.h5", "missing.h5: no such file"},
      {"--param young --target not_hdf5.h5", "not_hdf5.h5: not an HDF5 file"},
      {"--param young --target other.h5", "other.h5: no body 'beam'"},
      {"--param young --target target.h5 --frames 9", "--frames 9: frame 9 is not in the target"},
      {"--param young --target target.h5 --frames 0", "--frames 0: frame 0 is the initial state"},
      {"--param young --target target.h5 --frames first", "--frames first: expected last, all or a list"},
      {"--param young --target target.h5 --set simulation.dt=0.003", "is not a multiple of the scene's dt"},
      {"--param young --markers bad_header.csv", "bad_header.csv:1: expected the header line 'time,marker,x,y,z'"},
      {"--param young --markers bad_number.csv", "bad_number.csv:3: y: expected a finite number, got 'zero'"},
      {"--param young --markers bad_fields.csv", "bad_fields.csv:2: expected 5 comma-separated fields"},
      {"--param young --markers outside.csv", "outside.csv:2: marker 'a' at time 0 is not inside any body"},
      {"--param young --markers unembedded.csv", "marker 'a' is neither an effector of the scene nor observed at time 0"},
      {"--param young --markers off_step.csv", "off_step.csv:3: the observation at time 0.015 s is not a multiple"},
      {"--param young --markers missing.csv", "missing.csv: cannot be opened"},
      {"--param young --markers bad_header.csv --frames last", "--frames selects frames of --target"},
      {"--param young --target target.h5 -o exists.h5", "exists.h5: exists (use --force to overwrite)"},
  };
  for (const Case& c : cases) {
    const bool to_existing = c.args.find("exists.h5") != std::string::npos;
    const std::string out = to_existing ? "" : " -o out.h5";
    const CliRun r = run_cli("calibrate scene.yaml " + c.args + out, dir);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(r.err.find('\n'), r.err.size() - 1) << "one line: " << r.err;
    EXPECT_FALSE(fs::exists(dir / "out.h5")) << c.args;
    EXPECT_FALSE(fs::exists(dir / "out.h5.partial")) << c.args;
    EXPECT_EQ(read_text(dir / "exists.h5"), "x");
  }
}

}  // namespace
