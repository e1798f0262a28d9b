// The output as other tools read it (docs/output.md): meshio 7 reads the XDMF files
// (Debian's python3-meshio, run with /usr/bin/python3); every dataset of every
// command's file has a `units` attribute and is listed in docs/output.md; counts and
// flags are integer attributes; /bodies/<b>/contact_force is the nodal sum of the
// contacts' world forces; output.compression keeps every value, and a bad value is
// exit 2 naming the scene line.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <map>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_output_format";
const char* kPython = "/usr/bin/python3";

// The shipped beam (0.2 x 0.02 x 0.02 m) 0.5 mm above a floor, falling onto it, with
// a cable, a translation servo and an effector; `second` adds a second beam beside it.
std::string scene(bool second = false, const std::string& output = "output: {fields: [x, v]}\n", int steps = 8) {
  const std::string body =
      "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
      "    material: {law: corotational, young: 1.0e5, poisson: 0.3, density: 1000}\n";
  return "softdiff: 1\n"
         "simulation: {dt: 0.005, steps: " + std::to_string(steps) + "}\n"
         "bodies:\n"
         "  - name: beam\n" + body +
         "    translate: [0, 0, 0.0005]\n"
         "    actuators:\n"
         "      - {name: cable, type: cable, points: [[0.1, 0.01, 0.0105], [0.19, 0.01, 0.0105]], force: 0.05}\n"
         "      - {name: push, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 1, 0], force: 0.01, "
         "limits: [-0.05, 0.05]}\n"
         "    effectors:\n"
         "      - {name: tip, point: [0.2, 0.01, 0.0105]}\n" +
         (second ? "  - name: beam2\n" + body + "    translate: [0, 0.05, 0.0005]\n" : std::string()) +
         "obstacles:\n"
         "  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0}\n"
         "contact: {friction: 0.5, margin: 0.001}\n" + output;
}

std::string quoted(const fs::path& p) { return "'" + p.string() + "'"; }

// Runs the meshio check (tests/app/meshio_read_xdmf.py) of one XDMF file.
CliRun meshio_check(const fs::path& dir, const std::string& h5, const std::string& body, const std::string& xmf) {
  const fs::path out = dir / ("meshio_" + xmf + ".txt");
  const std::string command = std::string(kPython) + " " + quoted(kRoot / "tests/app/meshio_read_xdmf.py") + " " +
                              quoted(dir / h5) + " " + body + " " + quoted(dir / xmf) + " > " + quoted(out) +
                              " 2>&1";
  const int status = std::system(command.c_str());
  CliRun r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = read_text(out);
  return r;
}

// ---------------------------------------------------------------------------
// Walking a file: every dataset (path, its `units` attribute or "<missing>").

struct Walk {
  std::map<std::string, std::string> units;  // dataset path -> units
};

herr_t visit(hid_t object, const char* name, const H5O_info_t* info, void* data) {
  if (info->type != H5O_TYPE_DATASET) return 0;
  auto* walk = static_cast<Walk*>(data);
  const std::string path = "/" + std::string(name);
  std::string units = "<missing>";
  if (H5Aexists_by_name(object, name, "units", H5P_DEFAULT) > 0) {
    const hid_t a = H5Aopen_by_name(object, name, "units", H5P_DEFAULT, H5P_DEFAULT);
    const hid_t type = H5Aget_type(a);
    if (H5Tget_class(type) == H5T_STRING) units = h5_string_attribute(object, path, "units");
    else units = "<not a string>";
    H5Tclose(type);
    H5Aclose(a);
  }
  walk->units[path] = units;
  return 0;
}

Walk walk_file(const fs::path& file) {
  Walk walk;
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  EXPECT_GE(f, 0) << file;
  if (f < 0) return walk;
  H5Ovisit(f, H5_INDEX_NAME, H5_ITER_NATIVE, visit, &walk);
  H5Fclose(f);
  return walk;
}

// The dataset list of docs/output.md (the first ``` block): one regular expression
// per documented path, `<name>` standing for any one path component.
std::vector<std::pair<std::string, std::regex>> documented_paths() {
  const std::string text = read_text(kRoot / "docs/output.md");
  const auto begin = text.find("```\n");
  const auto end = text.find("```", begin + 4);
  EXPECT_NE(begin, std::string::npos);
  std::vector<std::pair<std::string, std::regex>> out;
  std::stringstream block(text.substr(begin + 4, end - begin - 4));
  for (std::string line; std::getline(block, line);) {
    if (line.empty() || line[0] != '/') continue;
    const std::string path = line.substr(0, line.find(' '));
    const std::string pattern = std::regex_replace(path, std::regex("<[^>]+>"), "[^/]+");
    out.emplace_back(path, std::regex(pattern));
  }
  return out;
}

// Every dataset of `file` has a units attribute (a string) and a documented path.
void expect_units_and_documented(const fs::path& file) {
  SCOPED_TRACE(file.filename().string());
  static const auto documented = documented_paths();
  const Walk walk = walk_file(file);
  EXPECT_FALSE(walk.units.empty());
  for (const auto& [path, units] : walk.units) {
    EXPECT_NE(units, "<missing>") << path << " has no units attribute";
    EXPECT_NE(units, "<not a string>") << path;
    EXPECT_FALSE(units.empty()) << path;
    bool listed = false;
    for (const auto& [doc, pattern] : documented) listed = listed || std::regex_match(path, pattern);
    EXPECT_TRUE(listed) << path << " is not listed in docs/output.md";
  }
}

H5T_class_t attribute_class(const fs::path& file, const std::string& object, const std::string& name) {
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  H5T_class_t c = H5T_NO_CLASS;
  const hid_t a = H5Aopen_by_name(f, object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
  if (a >= 0) {
    const hid_t type = H5Aget_type(a);
    c = H5Tget_class(type);
    H5Tclose(type);
    H5Aclose(a);
  }
  H5Fclose(f);
  return c;
}

std::string units_of(const fs::path& file, const std::string& path) {
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const std::string u = h5_string_attribute(f, path, "units");
  H5Fclose(f);
  return u;
}

// ---------------------------------------------------------------------------

// meshio 7 (Debian python3-meshio) reads the per-body XDMF files of a two-body run
// and the out.xmf of a one-body run: mesh, times, and every frame's x, v,
// displacement and contact_force equal to the HDF5 datasets.
TEST(CliOutputFormat, MeshioReadsEveryFrameOfEveryBody) {
  const auto dir = fresh_dir(kWork, "meshio");
  write_text(dir / "two.yaml", scene(true));
  const CliRun r = run_cli("simulate two.yaml -o two.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  for (const std::string body : {"beam", "beam2"}) {
    const CliRun m = meshio_check(dir, "two.h5", body, "two." + body + ".xmf");
    EXPECT_EQ(m.code, 0) << m.out;
    EXPECT_EQ(m.out, "ok " + body + " 9 contact_force,displacement,v,x\n");
  }
  write_text(dir / "one.yaml", scene(false, "output: {fields: [x]}\n"));
  ASSERT_EQ(run_cli("simulate one.yaml -o one.h5 --quiet", dir).code, 0);
  for (const std::string xmf : {"one.xmf", "one.beam.xmf"}) {
    const CliRun m = meshio_check(dir, "one.h5", "beam", xmf);
    EXPECT_EQ(m.code, 0) << xmf << ": " << m.out;
    EXPECT_EQ(m.out, "ok beam 9 contact_force,displacement,x\n") << xmf;
  }
}

// /bodies/beam/contact_force[k] is, per node, the sum of the world forces
// (frame . force) of frame k's contacts at that node (floor contacts: the contact
// point is the vertex at the start of the step, x[k-1]); zero at frame 0.
TEST(CliOutputFormat, ContactForceIsTheNodalSumOfTheContactForces) {
  const auto dir = fresh_dir(kWork, "contact_force");
  write_text(dir / "scene.yaml", scene());
  const CliRun r = run_cli("simulate scene.yaml -o out.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const hid_t f = H5Fopen((dir / "out.h5").c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  const auto shape = h5_shape(f, "/bodies/beam/x");
  ASSERT_EQ(shape.size(), 3u);
  EXPECT_EQ(h5_shape(f, "/bodies/beam/contact_force"), shape);
  const std::size_t T = shape[0], n = shape[1];
  const auto x = h5_read(f, "/bodies/beam/x"), force = h5_read(f, "/bodies/beam/contact_force");
  const auto point = h5_read(f, "/contact/point"), frame = h5_read(f, "/contact/frame"),
             lambda = h5_read(f, "/contact/force");
  std::vector<std::int64_t> offsets(T + 1);
  const hid_t d = H5Dopen2(f, "/contact/offsets", H5P_DEFAULT);
  ASSERT_GE(H5Dread(d, H5T_NATIVE_INT64, H5S_ALL, H5S_ALL, H5P_DEFAULT, offsets.data()), 0);
  H5Dclose(d);
  H5Fclose(f);
  ASSERT_GT(offsets.back(), 0) << "no contact: the test checks nothing";
  for (std::size_t k = 0; k < T; ++k) {
    std::vector<double> expected(3 * n, 0.0);
    for (std::int64_t c = offsets[k]; c < offsets[k + 1]; ++c) {
      // The node whose position at the start of the step is the contact point.
      std::size_t node = n;
      for (std::size_t i = 0; i < n && k > 0; ++i) {
        bool same = true;
        for (int a = 0; a < 3; ++a) same = same && x[((k - 1) * n + i) * 3 + a] == point[3 * c + a];
        if (same) node = i;
      }
      ASSERT_LT(node, n) << "frame " << k << " contact " << c << ": no node at the contact point";
      for (int a = 0; a < 3; ++a)  // row a of the frame: component a of t1, t2, n
        for (int j = 0; j < 3; ++j) expected[3 * node + a] += frame[9 * c + 3 * a + j] * lambda[3 * c + j];
    }
    for (std::size_t e = 0; e < 3 * n; ++e)
      ASSERT_NEAR(force[3 * n * k + e], expected[e], 1e-12 * (1 + std::abs(expected[e])))
          << "frame " << k << " node " << e / 3 << " component " << e % 3;
  }
  EXPECT_EQ(units_of(dir / "out.h5", "/bodies/beam/contact_force"), "N");
  EXPECT_EQ(units_of(dir / "out.h5", "/bodies/beam/displacement"), "m");
}

// Every dataset written by simulate (actuators, effectors, contact, v), simulate
// --jacobian, calibrate and control has a units attribute and is listed in
// docs/output.md; counts and flags are integers.
TEST(CliOutputFormat, EveryDatasetHasUnitsAndIsDocumented) {
  const auto dir = fresh_dir(kWork, "units");
  write_text(dir / "scene.yaml", scene());
  const CliRun s = run_cli("simulate scene.yaml -o sim.h5 --quiet --jacobian young,poisson,actuation", dir);
  ASSERT_EQ(s.code, 0) << s.err;
  expect_units_and_documented(dir / "sim.h5");
  const fs::path sim = dir / "sim.h5";
  EXPECT_EQ(units_of(sim, "/actuators/cable/value"), "N");
  EXPECT_EQ(units_of(sim, "/actuators/cable/length"), "m");
  EXPECT_EQ(units_of(sim, "/actuators/push/value"), "N");
  EXPECT_EQ(units_of(sim, "/bodies/beam/effectors/tip"), "m");
  EXPECT_EQ(units_of(sim, "/bodies/beam/v"), "m/s");
  EXPECT_EQ(units_of(sim, "/contact/force"), "N");
  EXPECT_EQ(units_of(sim, "/time"), "s");
  EXPECT_EQ(units_of(sim, "/jacobians/young"), "m/Pa");
  EXPECT_EQ(units_of(sim, "/jacobians/actuation"), "m/N");
  EXPECT_EQ(units_of(sim, "/jacobians/poisson"), "m");
  for (const char* name : {"frame", "ncp_rank_deficient_steps", "nondifferentiable_contacts", "smoothed_contacts"})
    EXPECT_EQ(attribute_class(sim, "/jacobians/young", name), H5T_INTEGER) << name;
  EXPECT_EQ(attribute_class(sim, "/", "softdiff_format"), H5T_INTEGER);

  // calibrate: young from a target made with the scene's value.
  write_text(dir / "calibrate.yaml", scene(false, "", 4));
  ASSERT_EQ(run_cli("simulate calibrate.yaml -o target.h5 --quiet", dir).code, 0);
  const CliRun c = run_cli("calibrate calibrate.yaml --param young --init 8e4 --target target.h5 -o cal.h5 --quiet", dir);
  ASSERT_EQ(c.code, 0) << c.err;
  expect_units_and_documented(dir / "cal.h5");
  for (const char* name : {"converged", "iterations", "evaluations"})
    EXPECT_EQ(attribute_class(dir / "cal.h5", "/calibration", name), H5T_INTEGER) << name;
  EXPECT_EQ(attribute_class(dir / "cal.h5", "/calibration", "young"), H5T_FLOAT);
  EXPECT_EQ(attribute_class(dir / "cal.h5", "/calibration", "final_cost"), H5T_FLOAT);
  EXPECT_EQ(units_of(dir / "cal.h5", "/calibration/iterations"), "1,Pa,m^2,m^2/Pa,1,s");

  // control: the servo drives the tip towards a point.
  const CliRun k = run_cli("control scene.yaml --effector tip --target=0.2,0.012,0.0105 -o control.h5 --quiet", dir);
  ASSERT_EQ(k.code, 0) << k.err;
  expect_units_and_documented(dir / "control.h5");
  EXPECT_EQ(units_of(dir / "control.h5", "/control/actuation"), "N");  // the cable's and the servo's
  EXPECT_EQ(units_of(dir / "control.h5", "/control/contact_force_norm"), "N");
}

// output.compression: gzip:1 and gzip:6 hold exactly the values of none, in chunks
// of one frame, deflated (and shuffled); the other datasets are not compressed.
TEST(CliOutputFormat, CompressionKeepsEveryValue) {
  const auto dir = fresh_dir(kWork, "compression");
  std::map<std::string, std::map<std::string, std::vector<double>>> values;  // setting -> path -> values
  for (const std::string setting : {"none", "gzip:1", "gzip:6", "gzip"}) {
    const std::string name = setting == "gzip" ? "gzip" : setting.substr(0, setting.find(':')) +
                                                              (setting.size() > 4 ? setting.substr(5) : "");
    write_text(dir / (name + ".yaml"), scene(false, "output: {fields: [x, v], compression: '" + setting + "'}\n"));
    const CliRun r = run_cli("simulate " + name + ".yaml -o " + name + ".h5 --quiet", dir);
    ASSERT_EQ(r.code, 0) << setting << ": " << r.err;
    const fs::path file = dir / (name + ".h5");
    const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    ASSERT_GE(f, 0);
    for (const auto& [path, units] : walk_file(file).units) {
      const hid_t d = H5Dopen2(f, path.c_str(), H5P_DEFAULT);
      const hid_t type = H5Dget_type(d);
      const bool numeric = H5Tget_class(type) != H5T_STRING;
      H5Tclose(type);
      const hid_t plist = H5Dget_create_plist(d);
      const int filters = H5Pget_layout(plist) == H5D_CHUNKED ? H5Pget_nfilters(plist) : 0;
      const bool frames = std::regex_match(path, std::regex("/bodies/beam/(x|v|displacement|contact_force)"));
      if (frames && setting != "none") {
        EXPECT_EQ(filters, 2) << setting << " " << path;
        unsigned flags = 0, level = 0;
        std::size_t count = 1;
        char filter_name[64];
        EXPECT_EQ(H5Pget_filter_by_id2(plist, H5Z_FILTER_DEFLATE, &flags, &count, &level, sizeof filter_name,
                                       filter_name, nullptr),
                  0);
        EXPECT_EQ(level, setting == "gzip:1" ? 1u : 6u) << setting;
        hsize_t chunk[3] = {0, 0, 0};
        EXPECT_EQ(H5Pget_chunk(plist, 3, chunk), 3);
        EXPECT_EQ(chunk[0], 1u) << "one frame per chunk";
      } else {
        EXPECT_EQ(filters, 0) << setting << " " << path;
      }
      H5Pclose(plist);
      H5Dclose(d);
      if (numeric) values[setting][path] = h5_read(f, path);
    }
    H5Fclose(f);
  }
  ASSERT_GT(values["none"].count("/bodies/beam/x"), 0u);
  for (const std::string setting : {"gzip:1", "gzip:6", "gzip"}) {
    ASSERT_EQ(values[setting].size(), values["none"].size()) << setting;
    for (const auto& [path, v] : values["none"]) {
      if (path == "/solver/step_seconds") continue;  // wall times
      EXPECT_EQ(values[setting][path], v) << setting << " " << path;
    }
  }
}

// A bad output.compression is exit 2 naming the scene file, line and key, and
// writes nothing.
TEST(CliOutputFormat, BadCompressionIsExit2WithTheSceneLocation) {
  for (const std::string bad : {"gzip:10", "zstd", "gzip:0", "gzip:", "gzip:6x", "lzf"}) {
    SCOPED_TRACE(bad);
    const auto dir = fresh_dir(kWork, "bad_compression");
    const std::string text = scene(false, "output:\n  every: 1\n  compression: '" + bad + "'\n");
    write_text(dir / "scene.yaml", text);
    const CliRun r = run_cli("simulate scene.yaml -o out.h5", dir);
    EXPECT_EQ(r.code, 2) << r.err;
    const std::size_t line = static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n'));  // the last line
    EXPECT_NE(r.err.find("scene.yaml:" + std::to_string(line) + ":3: output.compression: must be none, gzip or "
                         "gzip:LEVEL with LEVEL in 1..9; got '" + bad + "'"),
              std::string::npos)
        << r.err;
    for (const auto& entry : fs::directory_iterator(dir)) {
      const auto ext = entry.path().extension();
      EXPECT_TRUE(ext != ".h5" && ext != ".xmf" && ext != ".partial") << "left behind: " << entry.path();
    }
  }
}

}  // namespace
