// Hdf5Writer: the output file (spec: output.md) read back with the HDF5 C API, its
// safety rules (no overwrite, .partial + rename, interruption), crash readability
// and the XDMF file beside it.
#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/xdmf.hpp>
#include <softdiff/version.hpp>

#include <gtest/gtest.h>
#if __has_include(<hdf5.h>)
#include <hdf5.h>
#else
#include <hdf5/serial/hdf5.h>  // Debian: the test target does not see HDF5's include folder
#endif
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cctype>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <regex>
#include <sstream>
#include <tuple>
#include <string>
#include <vector>

namespace fs = std::filesystem;
using softdiff::ComputationError;
using softdiff::InputError;
using softdiff::MatX;
using softdiff::VecX;
using softdiff::io::Hdf5Writer;
using softdiff::io::OutputBody;
using softdiff::io::WriterOptions;

namespace {

// ---------------------------------------------------------------------------
// Fixtures: two small bodies and deterministic frames

std::vector<OutputBody> two_bodies() {
  OutputBody beam;
  beam.name = "beam";
  beam.rest.resize(3, 5);
  for (int i = 0; i < 5; ++i) beam.rest.col(i) << 0.1 * i, 0.01 * i, -0.5 * i;
  beam.tets.resize(4, 2);
  beam.tets << 0, 1, 1, 2, 2, 3, 3, 4;
  beam.surface.resize(3, 3);
  beam.surface << 0, 1, 2, 1, 2, 3, 2, 3, 4;
  OutputBody ball;
  ball.name = "ball";
  ball.rest.resize(3, 4);
  ball.rest << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
  ball.tets.resize(4, 1);
  ball.tets << 0, 1, 2, 3;
  ball.surface.resize(3, 4);
  ball.surface << 0, 0, 0, 1, 2, 1, 3, 2, 1, 3, 2, 3;
  return {beam, ball};
}

constexpr int kNodes = 9;  // 5 + 4

double x_value(int frame, int entry) { return 1000.0 * frame + 0.25 * entry; }
double v_value(int frame, int entry) { return -100.0 * frame - entry; }
double time_value(int frame) { return 0.25 * frame; }

void append_frames(Hdf5Writer& writer, int first, int count, bool with_v) {
  VecX x(3 * kNodes), v(3 * kNodes);
  for (int k = first; k < first + count; ++k) {
    for (int e = 0; e < 3 * kNodes; ++e) {
      x[e] = x_value(k, e);
      v[e] = v_value(k, e);
    }
    writer.append_frame(time_value(k), x, with_v ? &v : nullptr, k == 0 ? 0.0 : 0.5 + k);
  }
}

// A clean folder per test (tests may run in parallel processes).
fs::path test_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "io_hdf5_writer" / (std::string(info->name()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

WriterOptions options_for(const fs::path& file, bool write_v = true) {
  WriterOptions options;
  options.file = file;
  options.write_v = write_v;
  options.command = "softdiff simulate scene.yaml -o " + file.filename().string();
  options.scene_yaml = "bodies:\n  beam: {mesh: beam.msh}\n  ball: {mesh: ball.msh}\n";
  options.flush_every = 2;
  return options;
}

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

// ---------------------------------------------------------------------------
// Reading back with the HDF5 C API

struct H5File {
  hid_t id = -1;
  explicit H5File(const fs::path& path) {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    id = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  }
  ~H5File() {
    if (id >= 0) H5Fclose(id);
  }
  H5File(const H5File&) = delete;
  H5File& operator=(const H5File&) = delete;
};

bool has_link(hid_t file, const std::string& path) { return H5Lexists(file, path.c_str(), H5P_DEFAULT) > 0; }

std::vector<hsize_t> shape_of(hid_t file, const std::string& path) {
  const hid_t dataset = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  if (dataset < 0) return {};
  const hid_t space = H5Dget_space(dataset);
  std::vector<hsize_t> dims(static_cast<std::size_t>(H5Sget_simple_extent_ndims(space)));
  H5Sget_simple_extent_dims(space, dims.data(), nullptr);
  H5Sclose(space);
  H5Dclose(dataset);
  return dims;
}

std::vector<hsize_t> max_shape_of(hid_t file, const std::string& path) {
  const hid_t dataset = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  const hid_t space = H5Dget_space(dataset);
  std::vector<hsize_t> dims(static_cast<std::size_t>(H5Sget_simple_extent_ndims(space)));
  std::vector<hsize_t> max_dims(dims.size());
  H5Sget_simple_extent_dims(space, dims.data(), max_dims.data());
  H5Sclose(space);
  H5Dclose(dataset);
  return max_dims;
}

// Whether the dataset's file type equals `type` (e.g. H5T_STD_I64LE).
bool stored_as(hid_t file, const std::string& path, hid_t type) {
  const hid_t dataset = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  const hid_t stored = H5Dget_type(dataset);
  const bool same = H5Tequal(stored, type) > 0;
  H5Tclose(stored);
  H5Dclose(dataset);
  return same;
}

template <class T>
std::vector<T> read_all(hid_t file, const std::string& path, hid_t memory_type) {
  std::size_t count = 1;
  for (const hsize_t d : shape_of(file, path)) count *= static_cast<std::size_t>(d);
  std::vector<T> values(count);
  const hid_t dataset = H5Dopen2(file, path.c_str(), H5P_DEFAULT);
  EXPECT_GE(dataset, 0) << path;
  if (count > 0) {
    EXPECT_GE(H5Dread(dataset, memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()), 0) << path;
  }
  H5Dclose(dataset);
  return values;
}

std::vector<double> read_doubles(hid_t file, const std::string& path) {
  return read_all<double>(file, path, H5T_NATIVE_DOUBLE);
}
std::vector<long long> read_int64s(hid_t file, const std::string& path) {
  return read_all<long long>(file, path, H5T_NATIVE_LLONG);
}

std::string string_attribute(hid_t file, const std::string& object, const std::string& name) {
  const hid_t attribute = H5Aopen_by_name(file, object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
  if (attribute < 0) return "<missing>";
  const hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, H5T_VARIABLE);
  H5Tset_cset(type, H5T_CSET_UTF8);
  char* text = nullptr;
  std::string value = "<unreadable>";
  if (H5Aread(attribute, type, &text) >= 0 && text != nullptr) {
    value = text;
    H5free_memory(text);
  }
  H5Tclose(type);
  H5Aclose(attribute);
  return value;
}

template <class T>
T number_attribute(hid_t file, const std::string& object, const std::string& name, hid_t memory_type) {
  T value{};
  const hid_t attribute = H5Aopen_by_name(file, object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
  EXPECT_GE(attribute, 0) << object << " @" << name;
  if (attribute >= 0) {
    EXPECT_GE(H5Aread(attribute, memory_type, &value), 0);
    H5Aclose(attribute);
  }
  return value;
}

bool attribute_class_is(hid_t file, const std::string& object, const std::string& name, H5T_class_t type_class) {
  const hid_t attribute = H5Aopen_by_name(file, object.c_str(), name.c_str(), H5P_DEFAULT, H5P_DEFAULT);
  if (attribute < 0) return false;
  const hid_t type = H5Aget_type(attribute);
  const bool same = H5Tget_class(type) == type_class;
  H5Tclose(type);
  H5Aclose(attribute);
  return same;
}

// Frames 0..frames-1 of every dataset, as written by append_frames.
void expect_frames(hid_t file, int frames, bool with_v) {
  const auto T = static_cast<hsize_t>(frames);
  EXPECT_EQ(shape_of(file, "/time"), std::vector<hsize_t>({T}));
  EXPECT_EQ(shape_of(file, "/solver/step_seconds"), std::vector<hsize_t>({T}));
  const auto time = read_doubles(file, "/time");
  const auto seconds = read_doubles(file, "/solver/step_seconds");
  for (int k = 0; k < frames; ++k) {
    EXPECT_EQ(time[static_cast<std::size_t>(k)], time_value(k));
    EXPECT_EQ(seconds[static_cast<std::size_t>(k)], k == 0 ? 0.0 : 0.5 + k);
  }
  const std::vector<std::pair<std::string, int>> bodies{{"beam", 5}, {"ball", 4}};
  int first_node = 0;
  for (const auto& [name, nodes] : bodies) {
    const auto n = static_cast<hsize_t>(nodes);
    for (const std::string field : {"x", "v"}) {
      const std::string path = "/bodies/" + name + "/" + field;
      if (field == "v" && !with_v) {
        EXPECT_FALSE(has_link(file, path));
        continue;
      }
      ASSERT_EQ(shape_of(file, path), std::vector<hsize_t>({T, n, 3})) << path;
      EXPECT_EQ(max_shape_of(file, path)[0], H5S_UNLIMITED) << path;
      const auto values = read_doubles(file, path);
      for (int k = 0; k < frames; ++k)
        for (int e = 0; e < 3 * nodes; ++e) {
          const double expected = field == "x" ? x_value(k, 3 * first_node + e) : v_value(k, 3 * first_node + e);
          ASSERT_EQ(values[static_cast<std::size_t>(k * 3 * nodes + e)], expected) << path << " frame " << k;
        }
    }
    first_node += nodes;
  }
}

// ---------------------------------------------------------------------------
// A small XML well-formedness check (elements nest and close, attributes are
// quoted, no stray '<' or '&' in text).

bool well_formed_xml(const std::string& text, std::string& problem) {
  std::vector<std::string> open;
  std::size_t at = 0;
  const auto name_char = [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == ':' || c == '-' || c == '.'; };
  bool root_seen = false;
  while (at < text.size()) {
    if (text[at] != '<') {
      if (text[at] == '&') {
        const auto end = text.find(';', at);
        const std::string entity = text.substr(at, end == std::string::npos ? 0 : end - at + 1);
        if (entity != "&amp;" && entity != "&lt;" && entity != "&gt;" && entity != "&quot;" && entity != "&apos;") {
          problem = "bad entity at " + std::to_string(at);
          return false;
        }
      } else if (open.empty() && !std::isspace(static_cast<unsigned char>(text[at]))) {
        problem = "text outside the root element at " + std::to_string(at);
        return false;
      }
      ++at;
      continue;
    }
    if (text.compare(at, 5, "<?xml") == 0 && at == 0) {
      at = text.find("?>", at);
      if (at == std::string::npos) return problem = "unterminated declaration", false;
      at += 2;
      continue;
    }
    if (text.compare(at, 4, "<!--") == 0) {
      at = text.find("-->", at);
      if (at == std::string::npos) return problem = "unterminated comment", false;
      at += 3;
      continue;
    }
    const bool closing = text.compare(at, 2, "</") == 0;
    std::size_t p = at + (closing ? 2 : 1);
    const std::size_t name_start = p;
    while (p < text.size() && name_char(text[p])) ++p;
    const std::string name = text.substr(name_start, p - name_start);
    if (name.empty()) return problem = "empty tag name at " + std::to_string(at), false;
    // attributes
    while (p < text.size() && text[p] != '>' && !(text[p] == '/' && p + 1 < text.size() && text[p + 1] == '>')) {
      if (std::isspace(static_cast<unsigned char>(text[p]))) {
        ++p;
        continue;
      }
      if (closing) return problem = "attribute in closing tag " + name, false;
      const std::size_t attribute_start = p;
      while (p < text.size() && name_char(text[p])) ++p;
      if (p == attribute_start || p >= text.size() || text[p] != '=' || p + 1 >= text.size() ||
          (text[p + 1] != '"' && text[p + 1] != '\''))
        return problem = "bad attribute in <" + name + "> at " + std::to_string(p), false;
      const char quote = text[p + 1];
      const std::size_t end = text.find(quote, p + 2);
      if (end == std::string::npos) return problem = "unterminated attribute value", false;
      if (text.substr(p + 2, end - p - 2).find('<') != std::string::npos)
        return problem = "'<' in an attribute value", false;
      p = end + 1;
    }
    if (p >= text.size()) return problem = "unterminated tag " + name, false;
    const bool self_closing = text[p] == '/';
    at = p + (self_closing ? 2 : 1);
    if (closing) {
      if (open.empty() || open.back() != name) return problem = "</" + name + "> does not close an open element", false;
      open.pop_back();
    } else if (!self_closing) {
      if (open.empty() && root_seen) return problem = "a second root element <" + name + ">", false;
      root_seen = true;
      open.push_back(name);
    }
  }
  if (!open.empty()) return problem = "<" + open.back() + "> is not closed", false;
  return root_seen || (problem = "no root element", false);
}

int count_of(const std::string& text, const std::string& what) {
  int count = 0;
  for (auto at = text.find(what); at != std::string::npos; at = text.find(what, at + what.size())) ++count;
  return count;
}

// Runs `body` in a child process (for crash and resource-limit scenarios) and
// returns its exit code (-1 if it did not exit normally). The child never
// returns into the test framework.
template <class Body>
int run_in_child(Body body) {
  std::cout.flush();
  std::cerr.flush();
  const pid_t pid = ::fork();
  if (pid == 0) {
    int code = 99;
    try {
      code = body();
    } catch (const std::exception& e) {
      std::cerr << "child: unexpected exception: " << e.what() << "\n";
    } catch (...) {
    }
    std::cerr.flush();
    ::_exit(code);
  }
  int status = 0;
  if (pid < 0 || ::waitpid(pid, &status, 0) != pid) return -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// ---------------------------------------------------------------------------

TEST(Hdf5Writer, WritesEveryDatasetAndAttribute) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  const WriterOptions options = options_for(file);
  {
    Hdf5Writer writer(options, two_bodies());
    EXPECT_EQ(writer.final_path(), file);
    EXPECT_TRUE(fs::exists(dir / "out.h5.partial"));
    EXPECT_FALSE(fs::exists(file));
    append_frames(writer, 0, 5, true);
    EXPECT_EQ(writer.frames_written(), 5);
    writer.finish("complete");
    writer.finish("complete");  // idempotent
  }
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
  ASSERT_TRUE(fs::exists(file));

  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  EXPECT_EQ(number_attribute<int>(h5.id, "/", "softdiff_format", H5T_NATIVE_INT), 1);
  EXPECT_EQ(string_attribute(h5.id, "/", "softdiff_version"), SOFTDIFF_VERSION);
  EXPECT_EQ(string_attribute(h5.id, "/", "command"), options.command);
  EXPECT_EQ(string_attribute(h5.id, "/", "scene_yaml"), options.scene_yaml);
  EXPECT_EQ(string_attribute(h5.id, "/", "status"), "complete");
  EXPECT_TRUE(std::regex_match(string_attribute(h5.id, "/", "created"),
                               std::regex(R"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ)")))
      << string_attribute(h5.id, "/", "created");

  const auto bodies = two_bodies();
  for (const OutputBody& body : bodies) {
    const std::string group = "/bodies/" + body.name;
    const auto n = static_cast<hsize_t>(body.rest.cols());
    const auto m = static_cast<hsize_t>(body.tets.cols());
    const auto k = static_cast<hsize_t>(body.surface.cols());
    EXPECT_EQ(shape_of(h5.id, group + "/rest"), std::vector<hsize_t>({n, 3}));
    EXPECT_EQ(shape_of(h5.id, group + "/tets"), std::vector<hsize_t>({m, 4}));
    EXPECT_EQ(shape_of(h5.id, group + "/surface"), std::vector<hsize_t>({k, 3}));
    EXPECT_TRUE(stored_as(h5.id, group + "/rest", H5T_IEEE_F64LE));
    EXPECT_TRUE(stored_as(h5.id, group + "/tets", H5T_STD_I64LE));
    EXPECT_TRUE(stored_as(h5.id, group + "/surface", H5T_STD_I64LE));
    EXPECT_TRUE(stored_as(h5.id, group + "/x", H5T_IEEE_F64LE));
    const auto rest = read_doubles(h5.id, group + "/rest");
    const auto tets = read_int64s(h5.id, group + "/tets");
    const auto surface = read_int64s(h5.id, group + "/surface");
    for (Eigen::Index i = 0; i < body.rest.cols(); ++i)
      for (int c = 0; c < 3; ++c) EXPECT_EQ(rest[static_cast<std::size_t>(3 * i + c)], body.rest(c, i));
    for (Eigen::Index i = 0; i < body.tets.cols(); ++i)
      for (int c = 0; c < 4; ++c) EXPECT_EQ(tets[static_cast<std::size_t>(4 * i + c)], body.tets(c, i));
    for (Eigen::Index i = 0; i < body.surface.cols(); ++i)
      for (int c = 0; c < 3; ++c) EXPECT_EQ(surface[static_cast<std::size_t>(3 * i + c)], body.surface(c, i));
  }
  expect_frames(h5.id, 5, true);
}

// Every plain HDF DataItem of an XDMF text: (dimensions, file name, dataset path).
std::vector<std::array<std::string, 3>> heavy_references(const std::string& text) {
  const std::regex heavy(R"re(<DataItem Dimensions="([0-9 ]+)"[^>]*Format="HDF">([^<:|]+):([^<|]+)</DataItem>)re");
  std::vector<std::array<std::string, 3>> out;
  for (auto it = std::sregex_iterator(text.begin(), text.end(), heavy); it != std::sregex_iterator(); ++it)
    out.push_back({(*it)[1].str(), (*it)[2].str(), (*it)[3].str()});
  return out;
}

// The XDMF files of a 5-frame run of two bodies: out.xmf (both, ParaView) and one per
// body (meshio: one mesh per file). Every DataItem names a whole dataset of the .h5
// (no slab, no HyperSlab: meshio reads nothing else), of the stated shape; the views
// of frame k hold frame k of the source dataset.
TEST(Hdf5Writer, XdmfDescribesEveryFrameOfEveryBody) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "run 1.h5";  // a space, as users do
  {
    Hdf5Writer writer(options_for(file), two_bodies());
    append_frames(writer, 0, 5, true);
    writer.finish("complete");
  }
  for (const std::string name : {"run 1.xmf", "run 1.beam.xmf", "run 1.ball.xmf"}) {
    ASSERT_TRUE(fs::exists(dir / name)) << name;
    EXPECT_FALSE(fs::exists(dir / (name + ".partial"))) << name;
  }
  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  const auto shape_text = [&](const std::string& path) {
    std::ostringstream shape;
    for (const hsize_t d : shape_of(h5.id, path)) shape << (shape.tellp() > 0 ? " " : "") << d;
    return shape.str();
  };
  const std::map<std::string, int> first_node{{"beam", 0}, {"ball", 5}};
  const auto check = [&](const std::string& name, const std::vector<std::string>& bodies) {
    SCOPED_TRACE(name);
    const std::string text = read_text(dir / name);
    std::string problem;
    EXPECT_TRUE(well_formed_xml(text, problem)) << problem << "\n" << text;
    if (fs::exists("/usr/bin/xmllint")) {
      const std::string command = "/usr/bin/xmllint --noout '" + (dir / name).string() + "'";
      EXPECT_EQ(std::system(command.c_str()), 0) << command;
    }
    const int b = static_cast<int>(bodies.size());
    EXPECT_EQ(count_of(text, "<Xdmf Version=\"3.0\">"), 1);
    EXPECT_EQ(count_of(text, "CollectionType=\"Temporal\""), 1);
    EXPECT_EQ(count_of(text, "CollectionType=\"Spatial\""), b > 1 ? 5 : 0);
    EXPECT_EQ(count_of(text, "HyperSlab"), 0);
    EXPECT_EQ(count_of(text, "<Time Value="), 5);
    for (const std::string& body : bodies) EXPECT_EQ(count_of(text, "<Grid Name=\"" + body + "\" GridType=\"Uniform\">"), 5);
    EXPECT_EQ(count_of(text, "TopologyType=\"Tetrahedron\""), 5 * b);
    for (const std::string field : {"x", "v", "displacement"})
      EXPECT_EQ(count_of(text, "<Attribute Name=\"" + field + "\" AttributeType=\"Vector\" Center=\"Node\">"), 5 * b);
    for (int k = 0; k < 5; ++k) {
      std::ostringstream time;
      time << "<Time Value=\"" << time_value(k) << "\"/>";
      EXPECT_EQ(count_of(text, time.str()), 1) << time.str();
    }
    int references = 0;
    for (const auto& [dimensions, file_name, path] : heavy_references(text)) {
      ++references;
      EXPECT_EQ(file_name, "run 1.h5");
      EXPECT_EQ(shape_text(path), dimensions) << path;
      std::smatch view;
      if (!std::regex_match(path, view, std::regex("/xdmf/(\\w+)/(\\w+)/(\\d+)"))) {
        EXPECT_TRUE(std::regex_match(path, std::regex("/bodies/\\w+/tets"))) << path;
        continue;
      }
      // The view holds frame k of /bodies/<body>/<field>.
      const std::string body = view[1], field = view[2];
      const int k = std::stoi(view[3]);
      const std::vector<double> values = read_doubles(h5.id, path);
      const int nodes = body == "beam" ? 5 : 4;
      ASSERT_EQ(values.size(), static_cast<std::size_t>(3 * nodes)) << path;
      const auto rest = two_bodies()[body == "beam" ? 0 : 1].rest;
      for (int e = 0; e < 3 * nodes; ++e) {
        const int entry = 3 * first_node.at(body) + e;
        const double expected = field == "x"   ? x_value(k, entry)
                                : field == "v" ? v_value(k, entry)
                                               : x_value(k, entry) - rest(e % 3, e / 3);
        ASSERT_EQ(values[static_cast<std::size_t>(e)], expected) << path << " entry " << e;
      }
    }
    EXPECT_EQ(references, 5 * b * 5);  // frames x bodies x (tets, x geometry, x, v, displacement)
  };
  check("run 1.xmf", {"beam", "ball"});
  check("run 1.beam.xmf", {"beam"});
  check("run 1.ball.xmf", {"ball"});
}

// ParaView itself (its Xdmf3 readers) shows every frame of every body: run when
// pvpython is installed (Debian: python3-paraview, scripts/setup --paraview),
// skipped otherwise.
TEST(Hdf5Writer, XdmfOpensInParaViewSlow) {
  const char* pvpython = "/usr/bin/pvpython";
  if (!fs::exists(pvpython)) GTEST_SKIP() << "pvpython not installed";
  const fs::path dir = test_dir();
  {
    Hdf5Writer writer(options_for(dir / "out.h5"), two_bodies());
    append_frames(writer, 0, 3, true);
    writer.finish("complete");
  }
  const fs::path script = fs::path(SOFTDIFF_SOURCE_DIR) / "tests" / "io" / "paraview_read_xdmf.py";
  const auto bodies = two_bodies();
  // name, the bodies it shows (index into two_bodies), first entry of each in x
  const std::vector<std::tuple<std::string, std::vector<int>>> files{
      {"out.xmf", {0, 1}}, {"out.beam.xmf", {0}}, {"out.ball.xmf", {1}}};
  for (const auto& [name, shown] : files) {
    SCOPED_TRACE(name);
    const fs::path listing = dir / (name + ".txt");
    const std::string command = std::string(pvpython) + " --force-offscreen-rendering '" + script.string() + "' '" +
                                fs::absolute(dir / name).string() + "' > '" + listing.string() + "' 2> '" +
                                (dir / "paraview.err").string() + "'";
    ASSERT_EQ(std::system(command.c_str()), 0) << command << "\n" << read_text(dir / "paraview.err");
    std::string expected;
    for (const std::string reader : {"Xdmf3ReaderT", "Xdmf3ReaderS"})
      for (int k = 0; k < 3; ++k)
        for (std::size_t block = 0; block < shown.size(); ++block) {
          const OutputBody& body = bodies[static_cast<std::size_t>(shown[block])];
          const int nodes = static_cast<int>(body.rest.cols());
          const int first_entry = shown[block] == 0 ? 0 : 15;
          double x_sum = 0, v_sum = 0, u_sum = 0;
          for (int e = 0; e < 3 * nodes; ++e) {
            x_sum += x_value(k, first_entry + e);
            v_sum += v_value(k, first_entry + e);
            u_sum += x_value(k, first_entry + e) - body.rest(e % 3, e / 3);
          }
          char line[256];
          std::snprintf(line, sizeof line, "%s %d %g %d %d %d %.6f %.6f %.6f\n", reader.c_str(), k, time_value(k),
                        static_cast<int>(block), nodes, static_cast<int>(body.tets.cols()), x_sum, v_sum, u_sum);
          expected += line;
        }
    EXPECT_EQ(read_text(listing), expected) << read_text(dir / "paraview.err");
  }
}

TEST(Hdf5Writer, WithoutVelocitiesWritesNoV) {
  const fs::path dir = test_dir();
  {
    Hdf5Writer writer(options_for(dir / "out.h5", /*write_v=*/false), two_bodies());
    append_frames(writer, 0, 3, false);
    writer.finish("complete");
  }
  H5File h5(dir / "out.h5");
  ASSERT_GE(h5.id, 0);
  expect_frames(h5.id, 3, false);
  const std::string text = read_text(dir / "out.xmf");
  EXPECT_EQ(count_of(text, "<Attribute Name=\"v\""), 0);
  EXPECT_EQ(count_of(text, "/v/"), 0);
  EXPECT_EQ(count_of(text, "<Attribute Name=\"displacement\""), 3 * 2);
  EXPECT_FALSE(has_link(h5.id, "/xdmf/beam/v"));
}

TEST(Hdf5Writer, ExistingFileIsNotOverwrittenWithoutForce) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  std::ofstream(file) << "precious";
  try {
    Hdf5Writer writer(options_for(file), two_bodies());
    FAIL() << "no InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), file.string() + ": output file exists (use --force to overwrite)");
  }
  EXPECT_EQ(read_text(file), "precious");
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
  EXPECT_FALSE(fs::exists(dir / "out.xmf"));
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);

  // A stale .xmf or .partial is not overwritten either.
  fs::remove(file);
  std::ofstream(dir / "out.xmf") << "mine";
  EXPECT_THROW(Hdf5Writer(options_for(file), two_bodies()), InputError);
  EXPECT_EQ(read_text(dir / "out.xmf"), "mine");
  fs::remove(dir / "out.xmf");
  std::ofstream(dir / "out.h5.partial") << "another run";
  EXPECT_THROW(Hdf5Writer(options_for(file), two_bodies()), InputError);
  EXPECT_EQ(read_text(dir / "out.h5.partial"), "another run");
  EXPECT_FALSE(fs::exists(file));
}

TEST(Hdf5Writer, ForceReplacesTheExistingFileAtFinish) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  std::ofstream(file) << "old";
  std::ofstream(dir / "out.xmf") << "old";
  std::ofstream(dir / "out.h5.partial") << "stale";
  WriterOptions options = options_for(file);
  options.force = true;
  {
    Hdf5Writer writer(options, two_bodies());
    append_frames(writer, 0, 2, true);
    EXPECT_EQ(read_text(file), "old");  // replaced only when the new file is complete
    writer.finish("complete");
  }
  EXPECT_GT(H5Fis_hdf5(file.c_str()), 0);
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
  EXPECT_NE(read_text(dir / "out.xmf"), "old");
  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  expect_frames(h5.id, 2, true);
}

// With force, an unfinished run (interrupted, diverged, failed) never replaces the
// existing file: its frames go to out.<kind>.h5 (and .xmf), the old pair stays.
TEST(Hdf5Writer, ForceKeepsTheExistingFileFromAnUnfinishedRun) {
  for (const std::string status : {"interrupted", "diverged: step 3: inverted element", "failed: no space"}) {
    const fs::path dir = test_dir();
    const fs::path file = dir / "out.h5";
    std::ofstream(file) << "old";
    std::ofstream(dir / "out.xmf") << "old";
    const std::string kind = status.substr(0, status.find(':'));
    const fs::path side = dir / ("out." + kind + ".h5");
    WriterOptions options = options_for(file);
    options.force = true;
    {
      Hdf5Writer writer(options, two_bodies());
      append_frames(writer, 0, 2, true);
      writer.finish(status);
      EXPECT_EQ(writer.final_path(), side);
    }
    EXPECT_EQ(read_text(file), "old") << status;
    EXPECT_EQ(read_text(dir / "out.xmf"), "old") << status;
    EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
    ASSERT_TRUE(fs::exists(dir / ("out." + kind + ".xmf"))) << status;
    EXPECT_NE(read_text(dir / ("out." + kind + ".xmf")).find("out." + kind + ".h5:/bodies/"), std::string::npos);
    H5File h5(side);
    ASSERT_GE(h5.id, 0) << status;
    EXPECT_EQ(string_attribute(h5.id, "/", "status"), status);
    expect_frames(h5.id, 2, true);
  }
}

TEST(Hdf5Writer, MissingOrUnusableFolderIsAnInputErrorAndCreatesNothing) {
  const fs::path dir = test_dir();
  EXPECT_THROW(Hdf5Writer(options_for(dir / "missing" / "out.h5"), two_bodies()), InputError);
  EXPECT_FALSE(fs::exists(dir / "missing"));

  std::ofstream(dir / "plain") << "a file, not a folder";
  EXPECT_THROW(Hdf5Writer(options_for(dir / "plain" / "out.h5"), two_bodies()), InputError);

  fs::create_directory(dir / "folder.h5");
  WriterOptions options = options_for(dir / "folder.h5");
  options.force = true;
  EXPECT_THROW(Hdf5Writer(options, two_bodies()), InputError);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 2);

  if (::geteuid() != 0) {  // root writes anywhere
    const fs::path locked = dir / "locked";
    fs::create_directory(locked);
    fs::permissions(locked, fs::perms::owner_read | fs::perms::owner_exec);
    EXPECT_THROW(Hdf5Writer(options_for(locked / "out.h5"), two_bodies()), InputError);
    fs::permissions(locked, fs::perms::owner_all);
    EXPECT_TRUE(fs::is_empty(locked));
  }
}

TEST(Hdf5Writer, NamesTheXdmfFileCannotReferenceAreRejected) {
  const fs::path dir = test_dir();
  EXPECT_THROW(Hdf5Writer(options_for(dir / "run:1.h5"), two_bodies()), InputError);
  EXPECT_THROW(Hdf5Writer(options_for(dir / "a|b.h5"), two_bodies()), InputError);
  EXPECT_THROW(Hdf5Writer(options_for(dir / "out.xmf"), two_bodies()), InputError);
  EXPECT_TRUE(fs::is_empty(dir));
}

TEST(Hdf5Writer, InvalidBodyNamesAreRejectedBeforeCreatingAnything) {
  const fs::path dir = test_dir();
  auto bodies = two_bodies();
  bodies[1].name = "a/b";
  EXPECT_THROW(Hdf5Writer(options_for(dir / "out.h5"), bodies), InputError);
  bodies[1].name = "beam";
  EXPECT_THROW(Hdf5Writer(options_for(dir / "out.h5"), bodies), InputError);
  EXPECT_TRUE(fs::is_empty(dir));
}

// Reached only when the run ends with an exception (its caller did not finish).
TEST(Hdf5Writer, DestructorWithoutFinishKeepsTheFramesAsFailed) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  {
    Hdf5Writer writer(options_for(file), two_bodies());
    append_frames(writer, 0, 3, true);  // flush_every = 2: frame 2 is not flushed yet
  }
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
  ASSERT_TRUE(fs::exists(file));
  EXPECT_TRUE(fs::exists(dir / "out.xmf"));
  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  EXPECT_EQ(string_attribute(h5.id, "/", "status"), "failed: the run ended with an error");
  expect_frames(h5.id, 3, true);
}

TEST(Hdf5Writer, FinishRecordsTheGivenStatus) {
  const fs::path dir = test_dir();
  {
    Hdf5Writer writer(options_for(dir / "out.h5"), two_bodies());
    append_frames(writer, 0, 1, true);
    writer.finish("diverged: Newton did not converge at step 1");
    EXPECT_THROW(append_frames(writer, 1, 1, true), std::logic_error);
  }
  H5File h5(dir / "out.h5");
  EXPECT_EQ(string_attribute(h5.id, "/", "status"), "diverged: Newton did not converge at step 1");
}

TEST(Hdf5Writer, AKilledRunLeavesEveryFlushedFrameReadable) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  const int code = run_in_child([&] {
    auto* writer = new Hdf5Writer(options_for(file), two_bodies());  // never destroyed: the process dies
    append_frames(*writer, 0, 5, true);  // flushed after frames 2 and 4; frame 5 not flushed
    return 0;                             // _exit: no destructor, no HDF5 close
  });
  ASSERT_EQ(code, 0);
  EXPECT_FALSE(fs::exists(file));
  const fs::path partial = dir / "out.h5.partial";
  ASSERT_TRUE(fs::exists(partial));

  H5File h5(partial);
  ASSERT_GE(h5.id, 0) << "the .partial file of a killed run does not open";
  EXPECT_EQ(string_attribute(h5.id, "/", "status"), "running");
  const std::vector<hsize_t> time_shape = shape_of(h5.id, "/time");
  ASSERT_EQ(time_shape.size(), 1u);
  EXPECT_GE(time_shape[0], 4u);
  expect_frames(h5.id, static_cast<int>(time_shape[0]), true);  // same T everywhere, values intact
}

TEST(Hdf5Writer, AFailedWriteIsAComputationErrorAndKeepsFramesConsistent) {
  // The child may only grow files to 200 kB (soft limit): a "disk full" (EFBIG) after
  // a few frames. It then lifts the limit, writes one more frame and finishes; the
  // file must hold the frames before the failure plus that one, with one T everywhere.
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  constexpr int kBig = 2000;  // 48 kB per frame
  const auto frame_value = [](int k) { return 10.0 * k; };
  const int code = run_in_child([&]() -> int {
    std::signal(SIGXFSZ, SIG_IGN);
    rlimit limit{};
    if (::getrlimit(RLIMIT_FSIZE, &limit) != 0) return 10;
    const rlim_t unlimited = limit.rlim_cur;
    limit.rlim_cur = 200 * 1024;
    if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) return 10;
    OutputBody big;
    big.name = "big";
    big.rest = softdiff::Mat3X::Zero(3, kBig);
    big.tets.resize(4, 1);
    big.tets << 0, 1, 2, 3;
    WriterOptions options = options_for(file, false);
    options.flush_every = 1;
    Hdf5Writer writer(options, {big});
    VecX x(3 * kBig);
    int k = 0;
    try {
      for (; k < 100; ++k) {
        x.setConstant(frame_value(k));
        writer.append_frame(k, x, nullptr, 0.0);
      }
      return 11;  // no failure?
    } catch (const ComputationError& e) {
      std::cerr << "child: expected failure after " << writer.frames_written() << " frames: " << e.what() << "\n";
      const std::string what = e.what();
      if (what.find("out.h5.partial") == std::string::npos || what.find("frame") == std::string::npos) return 12;
      if (what.find("File too large") == std::string::npos) return 13;
    }
    if (writer.frames_written() != k || k < 1) return 14;
    limit.rlim_cur = unlimited;
    if (::setrlimit(RLIMIT_FSIZE, &limit) != 0) return 15;
    x.setConstant(frame_value(k));
    writer.append_frame(k, x, nullptr, 0.0);  // the writer is still usable
    writer.finish("complete");
    return 0;
  });
  ASSERT_EQ(code, 0);
  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  const std::vector<hsize_t> time_shape = shape_of(h5.id, "/time");
  ASSERT_EQ(time_shape.size(), 1u);
  const hsize_t T = time_shape[0];
  EXPECT_GE(T, 2u);
  EXPECT_EQ(shape_of(h5.id, "/solver/step_seconds"), std::vector<hsize_t>({T}));
  EXPECT_EQ(shape_of(h5.id, "/bodies/big/x"), std::vector<hsize_t>({T, kBig, 3}));
  const auto time = read_doubles(h5.id, "/time");
  const auto x = read_doubles(h5.id, "/bodies/big/x");
  for (hsize_t k = 0; k < T; ++k) {
    EXPECT_EQ(time[k], static_cast<double>(k));
    EXPECT_EQ(x[k * 3 * kBig], frame_value(static_cast<int>(k)));
    EXPECT_EQ(x[(k + 1) * 3 * kBig - 1], frame_value(static_cast<int>(k)));
  }
  EXPECT_EQ(string_attribute(h5.id, "/", "status"), "complete");
}

TEST(Hdf5Writer, SeriesMatricesAndAttributesRoundTrip) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  {
    Hdf5Writer writer(options_for(file), two_bodies());
    const int value = writer.add_series("/actuators/cable/value", 0, "N");
    const int effector = writer.add_series("/bodies/beam/effectors/tip", 3, "m");
    EXPECT_THROW(writer.add_series("/time", 0, "s"), std::logic_error);
    for (int k = 0; k < 1500; ++k) {  // more than one chunk
      const double scalar = 0.5 * k;
      const double row[3] = {1.0 * k, 2.0 * k, 3.0 * k};
      writer.append_series(value, &scalar);
      writer.append_series(effector, row);
    }
    MatX jacobian(3, 2);
    jacobian << 1, 2, 3, 4, 5, 6;  // row-major reading order
    writer.write_matrix("/jacobians/young", jacobian, "m/Pa",
                        {{"theta", "beam.young"}, {"frame", std::int64_t{4}}, {"scale", 0.5}});
    EXPECT_THROW(writer.write_matrix("/jacobians/young", jacobian, "m/Pa"), std::logic_error);
    writer.set_attribute("/", "note", "hello");
    writer.set_attribute("/bodies/beam", "young", 2.5e5);
    writer.set_attribute("/bodies/beam", "young", 3.5e5);  // replaced
    writer.set_attribute("/jacobians", "frames", "last");
    writer.set_attribute("/jacobians", "count", 7);
    writer.set_attribute("/jacobians", "big", std::int64_t{1} << 40);
    EXPECT_THROW(writer.set_attribute("/calibration", "converged", 1), std::logic_error);
    writer.finish("complete");
  }
  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  EXPECT_EQ(shape_of(h5.id, "/actuators/cable/value"), std::vector<hsize_t>({1500}));
  EXPECT_EQ(shape_of(h5.id, "/bodies/beam/effectors/tip"), std::vector<hsize_t>({1500, 3}));
  const auto value = read_doubles(h5.id, "/actuators/cable/value");
  const auto tip = read_doubles(h5.id, "/bodies/beam/effectors/tip");
  for (std::size_t k = 0; k < 1500; ++k) {
    ASSERT_EQ(value[k], 0.5 * static_cast<double>(k));
    for (std::size_t c = 0; c < 3; ++c) ASSERT_EQ(tip[3 * k + c], static_cast<double>((c + 1) * k));
  }
  EXPECT_EQ(shape_of(h5.id, "/jacobians/young"), std::vector<hsize_t>({3, 2}));
  EXPECT_EQ(read_doubles(h5.id, "/jacobians/young"), std::vector<double>({1, 2, 3, 4, 5, 6}));
  EXPECT_EQ(string_attribute(h5.id, "/jacobians/young", "theta"), "beam.young");
  EXPECT_EQ(number_attribute<long long>(h5.id, "/jacobians/young", "frame", H5T_NATIVE_LLONG), 4);
  EXPECT_TRUE(attribute_class_is(h5.id, "/jacobians/young", "frame", H5T_INTEGER));
  EXPECT_TRUE(attribute_class_is(h5.id, "/jacobians/young", "scale", H5T_FLOAT));
  EXPECT_TRUE(attribute_class_is(h5.id, "/jacobians/young", "theta", H5T_STRING));
  EXPECT_EQ(number_attribute<long long>(h5.id, "/jacobians", "count", H5T_NATIVE_LLONG), 7);
  EXPECT_TRUE(attribute_class_is(h5.id, "/jacobians", "count", H5T_INTEGER));
  EXPECT_EQ(number_attribute<long long>(h5.id, "/jacobians", "big", H5T_NATIVE_LLONG), 1LL << 40);
  EXPECT_EQ(string_attribute(h5.id, "/actuators/cable/value", "units"), "N");
  EXPECT_EQ(string_attribute(h5.id, "/bodies/beam/effectors/tip", "units"), "m");
  EXPECT_EQ(string_attribute(h5.id, "/jacobians/young", "units"), "m/Pa");
  EXPECT_EQ(string_attribute(h5.id, "/", "note"), "hello");
  EXPECT_EQ(number_attribute<double>(h5.id, "/bodies/beam", "young", H5T_NATIVE_DOUBLE), 3.5e5);
  EXPECT_EQ(string_attribute(h5.id, "/jacobians", "frames"), "last");
}

TEST(Hdf5Writer, LargeSceneTextAndNoFrames) {
  const fs::path dir = test_dir();
  WriterOptions options = options_for(dir / "out.h5");
  options.scene_yaml = std::string(200000, 'y');  // beyond HDF5's 64 kB compact attribute limit
  {
    Hdf5Writer writer(options, two_bodies());
    writer.finish("complete");
  }
  H5File h5(dir / "out.h5");
  ASSERT_GE(h5.id, 0);
  EXPECT_EQ(string_attribute(h5.id, "/", "scene_yaml"), options.scene_yaml);
  expect_frames(h5.id, 0, true);
  std::string problem;
  EXPECT_TRUE(well_formed_xml(read_text(dir / "out.xmf"), problem)) << problem;
}

// Every dataset the writer creates, whatever the call, has a string `units`.
herr_t collect_units(hid_t object, const char* name, const H5O_info_t* info, void* data) {
  if (info->type == H5O_TYPE_DATASET) {
    auto* units = static_cast<std::map<std::string, std::string>*>(data);
    const hid_t attribute = H5Aopen_by_name(object, name, "units", H5P_DEFAULT, H5P_DEFAULT);
    std::string value = "<missing>";
    if (attribute >= 0) {
      value = string_attribute(object, name, "units");
      H5Aclose(attribute);
    }
    (*units)["/" + std::string(name)] = value;
  }
  return 0;
}

TEST(Hdf5Writer, EveryDatasetHasUnits) {
  const fs::path dir = test_dir();
  WriterOptions options = options_for(dir / "out.h5");
  options.write_contact_force = true;
  {
    Hdf5Writer writer(options, two_bodies());
    const int series = writer.add_series("/actuators/cavity/volume", 0, "m^3");
    const int table = writer.add_table("/contact/mode", {}, Hdf5Writer::Element::i8, "1");
    writer.write_strings("/contact/names", {"beam", "ball", "floor"}, "1");
    VecX x = VecX::Zero(3 * kNodes), force = VecX::Ones(3 * kNodes);
    for (int k = 0; k < 2; ++k) {
      writer.append_frame(k, x, &x, 0.0, &force);
      const double value = k;
      const std::int8_t mode = 1;
      writer.append_series(series, &value);
      writer.append_rows(table, &mode, 1);
    }
    writer.write_matrix("/jacobians/poisson", MatX::Ones(3 * kNodes, 2), "m");
    writer.finish("complete");
  }
  H5File h5(dir / "out.h5");
  ASSERT_GE(h5.id, 0);
  std::map<std::string, std::string> units;
  H5Ovisit(h5.id, H5_INDEX_NAME, H5_ITER_NATIVE, collect_units, &units);
  const std::map<std::string, std::string> expected_units{
      {"/time", "s"},           {"/solver/step_seconds", "s"}, {"/actuators/cavity/volume", "m^3"},
      {"/contact/mode", "1"},   {"/contact/names", "1"},       {"/jacobians/poisson", "m"}};
  for (const auto& [path, unit] : expected_units) EXPECT_EQ(units[path], unit) << path;
  for (const std::string body : {"beam", "ball"}) {
    const std::string group = "/bodies/" + body;
    EXPECT_EQ(units[group + "/rest"], "m");
    EXPECT_EQ(units[group + "/tets"], "1");
    EXPECT_EQ(units[group + "/surface"], "1");
    EXPECT_EQ(units[group + "/x"], "m");
    EXPECT_EQ(units[group + "/v"], "m/s");
    EXPECT_EQ(units[group + "/displacement"], "m");
    EXPECT_EQ(units[group + "/contact_force"], "N");
    for (int k = 0; k < 2; ++k) {
      const std::string frame = "/" + std::to_string(k);
      EXPECT_EQ(units["/xdmf/" + body + "/x" + frame], "m");
      EXPECT_EQ(units["/xdmf/" + body + "/v" + frame], "m/s");
      EXPECT_EQ(units["/xdmf/" + body + "/displacement" + frame], "m");
      EXPECT_EQ(units["/xdmf/" + body + "/contact_force" + frame], "N");
    }
  }
  EXPECT_EQ(units.size(), expected_units.size() + 2 * (7 + 2 * 4));
  for (const auto& [path, unit] : units) EXPECT_NE(unit, "<missing>") << path;
}

// /bodies/<b>/displacement = x - rest, /bodies/<b>/contact_force as given, both
// frame by frame, and both in the XDMF files.
TEST(Hdf5Writer, DisplacementAndContactForceFrames) {
  const fs::path dir = test_dir();
  WriterOptions options = options_for(dir / "out.h5");
  options.write_contact_force = true;
  const auto force_value = [](int frame, int entry) { return frame == 0 ? 0.0 : 0.5 * frame - 0.125 * entry; };
  {
    Hdf5Writer writer(options, two_bodies());
    VecX x(3 * kNodes), v(3 * kNodes), force(3 * kNodes);
    for (int k = 0; k < 3; ++k) {
      for (int e = 0; e < 3 * kNodes; ++e) {
        x[e] = x_value(k, e);
        v[e] = v_value(k, e);
        force[e] = force_value(k, e);
      }
      writer.append_frame(time_value(k), x, &v, k == 0 ? 0.0 : 0.5 + k, &force);
    }
    VecX wrong(3);
    EXPECT_THROW(writer.append_frame(1.0, x, &v, 0.0, &wrong), std::logic_error);
    EXPECT_THROW(writer.append_frame(1.0, x, &v, 0.0, nullptr), std::logic_error);
    writer.finish("complete");
  }
  H5File h5(dir / "out.h5");
  ASSERT_GE(h5.id, 0);
  expect_frames(h5.id, 3, true);
  int first_node = 0;
  for (const OutputBody& body : two_bodies()) {
    const auto n = static_cast<int>(body.rest.cols());
    const std::string group = "/bodies/" + body.name;
    ASSERT_EQ(shape_of(h5.id, group + "/displacement"), std::vector<hsize_t>({3, static_cast<hsize_t>(n), 3}));
    ASSERT_EQ(shape_of(h5.id, group + "/contact_force"), std::vector<hsize_t>({3, static_cast<hsize_t>(n), 3}));
    const auto u = read_doubles(h5.id, group + "/displacement");
    const auto f = read_doubles(h5.id, group + "/contact_force");
    for (int k = 0; k < 3; ++k)
      for (int e = 0; e < 3 * n; ++e) {
        const int entry = 3 * first_node + e;
        ASSERT_EQ(u[static_cast<std::size_t>(3 * n * k + e)], x_value(k, entry) - body.rest(e % 3, e / 3));
        ASSERT_EQ(f[static_cast<std::size_t>(3 * n * k + e)], force_value(k, entry));
      }
    first_node += n;
    const std::string text = read_text(dir / ("out." + body.name + ".xmf"));
    EXPECT_EQ(count_of(text, "<Attribute Name=\"contact_force\" AttributeType=\"Vector\" Center=\"Node\">"), 3);
    EXPECT_EQ(count_of(text, ":/xdmf/" + body.name + "/contact_force/2<"), 1);
  }
  EXPECT_EQ(count_of(read_text(dir / "out.xmf"), "<Attribute Name=\"contact_force\""), 2 * 3);
}

// gzip: the per-frame node datasets are shuffled and deflated, one frame per chunk,
// and read back identical to the uncompressed file; the other datasets are not
// filtered.
TEST(Hdf5Writer, CompressedFramesReadBackIdentical) {
  const fs::path dir = test_dir();
  for (const int level : {0, 1, 9}) {
    WriterOptions options = options_for(dir / ("out" + std::to_string(level) + ".h5"));
    options.gzip_level = level;
    options.write_contact_force = true;
    Hdf5Writer writer(options, two_bodies());
    VecX x(3 * kNodes), v(3 * kNodes);
    for (int k = 0; k < 4; ++k) {
      for (int e = 0; e < 3 * kNodes; ++e) {
        x[e] = x_value(k, e);
        v[e] = v_value(k, e);
      }
      writer.append_frame(time_value(k), x, &v, k == 0 ? 0.0 : 0.5 + k, &v);
    }
    writer.finish("complete");
  }
  H5File plain(dir / "out0.h5");
  for (const int level : {1, 9}) {
    H5File packed(dir / ("out" + std::to_string(level) + ".h5"));
    ASSERT_GE(packed.id, 0);
    expect_frames(packed.id, 4, true);
    for (const std::string body : {"beam", "ball"})
      for (const std::string field : {"x", "v", "displacement", "contact_force", "rest"}) {
        const std::string path = "/bodies/" + body + "/" + field;
        EXPECT_EQ(read_doubles(packed.id, path), read_doubles(plain.id, path)) << path;
        const hid_t dataset = H5Dopen2(packed.id, path.c_str(), H5P_DEFAULT);
        const hid_t creation = H5Dget_create_plist(dataset);
        if (field == "rest") {
          EXPECT_NE(H5Pget_layout(creation), H5D_CHUNKED) << path;
        } else {
          ASSERT_EQ(H5Pget_nfilters(creation), 2) << path;
          unsigned flags = 0, filter_config = 0;
          std::size_t count = 1;
          unsigned deflate_level = 0;
          EXPECT_EQ(H5Pget_filter2(creation, 0, &flags, &count, &deflate_level, 0, nullptr, &filter_config),
                    H5Z_FILTER_SHUFFLE);
          count = 1;
          EXPECT_EQ(H5Pget_filter2(creation, 1, &flags, &count, &deflate_level, 0, nullptr, &filter_config),
                    H5Z_FILTER_DEFLATE);
          EXPECT_EQ(deflate_level, static_cast<unsigned>(level));
          hsize_t chunk[3] = {0, 0, 0};
          ASSERT_EQ(H5Pget_chunk(creation, 3, chunk), 3);
          EXPECT_EQ(chunk[0], 1u);
          EXPECT_EQ(chunk[2], 3u);
        }
        H5Pclose(creation);
        H5Dclose(dataset);
      }
    const hid_t time = H5Dopen2(packed.id, "/time", H5P_DEFAULT);
    const hid_t creation = H5Dget_create_plist(time);
    EXPECT_EQ(H5Pget_nfilters(creation), 0);
    H5Pclose(creation);
    H5Dclose(time);
    // The views read through the compressed chunks.
    EXPECT_EQ(read_doubles(packed.id, "/xdmf/ball/v/3"), read_doubles(plain.id, "/xdmf/ball/v/3"));
  }
}

TEST(Hdf5Writer, ExistingPerBodyXdmfIsNotOverwrittenWithoutForce) {
  const fs::path dir = test_dir();
  std::ofstream(dir / "out.ball.xmf") << "mine";
  try {
    Hdf5Writer writer(options_for(dir / "out.h5"), two_bodies());
    FAIL() << "no InputError";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), (dir / "out.ball.xmf").string() + ": output file exists (use --force to overwrite)");
  }
  EXPECT_EQ(read_text(dir / "out.ball.xmf"), "mine");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
  WriterOptions options = options_for(dir / "out.h5");
  options.force = true;
  {
    Hdf5Writer writer(options, two_bodies());
    append_frames(writer, 0, 1, true);
    writer.finish("complete");
  }
  EXPECT_NE(read_text(dir / "out.ball.xmf"), "mine");
}

TEST(Hdf5Writer, LibraryVersion) {
  EXPECT_TRUE(std::regex_match(softdiff::io::hdf5_version(), std::regex(R"(1\.\d+\.\d+)")));
}

TEST(Xdmf, EscapesNames) {
  EXPECT_EQ(softdiff::io::xml_escape("a<b>&\"c'"), "a&lt;b&gt;&amp;&quot;c&apos;");
  const std::string text = softdiff::io::xdmf_text("R&D.h5", {{"b<1>", 4, 1}}, {0.0, 0.5}, {"x"});
  std::string problem;
  EXPECT_TRUE(well_formed_xml(text, problem)) << problem << "\n" << text;
  EXPECT_NE(text.find("R&amp;D.h5:/xdmf/b&lt;1&gt;/x/1<"), std::string::npos);
  EXPECT_NE(text.find("R&amp;D.h5:/bodies/b&lt;1&gt;/tets<"), std::string::npos);
  EXPECT_NE(text.find("<Time Value=\"0.5\"/>"), std::string::npos);
}

// A body without tets (a rigid body's surface, posed per frame in x): Triangle
// topology from its /bodies/<b>/surface; a body with neither tets nor triangles is
// still left out.
TEST(Xdmf, SurfaceOnlyBodyHasTriangleTopology) {
  const std::string text = softdiff::io::xdmf_text(
      "out.h5", {{"beam", 8, 6, 4, 0}, {"key", 8, 0, 4, 12}, {"empty", 0, 0, 4, 0}}, {0.0}, {"x"});
  std::string problem;
  EXPECT_TRUE(well_formed_xml(text, problem)) << problem << "\n" << text;
  EXPECT_NE(text.find("<Topology TopologyType=\"Tetrahedron\" NumberOfElements=\"6\">"), std::string::npos) << text;
  EXPECT_NE(text.find("<Topology TopologyType=\"Triangle\" NumberOfElements=\"12\">"), std::string::npos) << text;
  EXPECT_NE(text.find("Dimensions=\"12 3\" NumberType=\"Int\" Precision=\"8\" Format=\"HDF\">out.h5:/bodies/key/surface<"),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("out.h5:/xdmf/key/x/0<"), std::string::npos) << text;
  EXPECT_EQ(text.find("empty"), std::string::npos) << text;
}

}  // namespace
