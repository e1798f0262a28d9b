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

#include <cctype>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
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

TEST(Hdf5Writer, XdmfDescribesEveryFrameOfEveryBody) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "run 1.h5";  // a space, as users do
  {
    Hdf5Writer writer(options_for(file), two_bodies());
    append_frames(writer, 0, 5, true);
    writer.finish("complete");
  }
  const fs::path xmf = dir / "run 1.xmf";
  ASSERT_TRUE(fs::exists(xmf));
  EXPECT_FALSE(fs::exists(dir / "run 1.xmf.partial"));
  const std::string text = read_text(xmf);

  std::string problem;
  EXPECT_TRUE(well_formed_xml(text, problem)) << problem << "\n" << text;
  if (fs::exists("/usr/bin/xmllint")) {
    const std::string command = "/usr/bin/xmllint --noout '" + xmf.string() + "'";
    EXPECT_EQ(std::system(command.c_str()), 0) << command;
  }

  EXPECT_EQ(count_of(text, "CollectionType=\"Temporal\""), 1);
  EXPECT_EQ(count_of(text, "CollectionType=\"Spatial\""), 5);
  EXPECT_EQ(count_of(text, "<Grid Name=\"beam\" GridType=\"Uniform\">"), 5);
  EXPECT_EQ(count_of(text, "<Grid Name=\"ball\" GridType=\"Uniform\">"), 5);
  EXPECT_EQ(count_of(text, "TopologyType=\"Tetrahedron\""), 10);
  EXPECT_EQ(count_of(text, "<Attribute Name=\"v\" AttributeType=\"Vector\" Center=\"Node\">"), 10);
  for (int k = 0; k < 5; ++k) {
    std::ostringstream time;
    time << "<Time Value=\"" << time_value(k) << "\"/>";
    EXPECT_EQ(count_of(text, time.str()), 1) << time.str();
    // frame k: start (k, 0, 0), stride 1, count (1, n, 3) of the (T, n, 3) dataset
    EXPECT_EQ(count_of(text, "|" + std::to_string(k) + " 0 0:1 1 1:1 5 3:5 5 3<"), 2);  // beam: x and v
    EXPECT_EQ(count_of(text, "|" + std::to_string(k) + " 0 0:1 1 1:1 4 3:5 4 3<"), 2);  // ball
  }

  // Every heavy-data reference names the .h5 by file name and a dataset of the
  // stated shape (or, for a slab, a dataset of its dataspace holding the slab).
  H5File h5(dir / "run 1.h5");
  ASSERT_GE(h5.id, 0);
  const std::regex heavy(R"re(Dimensions="([0-9 ]+)"[^>]*Format="HDF">([^<:|]+):([^<|]+)(?:\|([^<]*))?</DataItem>)re");
  const auto shape_text = [&](const std::string& path) {
    std::ostringstream shape;
    for (const hsize_t d : shape_of(h5.id, path)) shape << (shape.tellp() > 0 ? " " : "") << d;
    return shape.str();
  };
  int references = 0;
  for (auto it = std::sregex_iterator(text.begin(), text.end(), heavy); it != std::sregex_iterator(); ++it) {
    ++references;
    const std::string dimensions = (*it)[1].str(), file_name = (*it)[2].str(), path = (*it)[3].str();
    EXPECT_EQ(file_name, "run 1.h5");
    if (!(*it)[4].matched) {
      EXPECT_EQ(shape_text(path), dimensions) << path;
      continue;
    }
    // start:stride:count:dataspace
    std::vector<std::string> parts;
    std::stringstream slab((*it)[4].str());
    for (std::string part; std::getline(slab, part, ':');) parts.push_back(part);
    ASSERT_EQ(parts.size(), 4u) << (*it)[4].str();
    EXPECT_EQ(parts[1], "1 1 1");
    EXPECT_EQ(parts[2], dimensions) << path;
    EXPECT_EQ(parts[3], shape_text(path)) << path;
    EXPECT_LT(std::stoi(parts[0]), 5) << path;
  }
  EXPECT_EQ(references, 5 * 2 * 3);  // frames x bodies x (tets, x, v)
  EXPECT_EQ(count_of(text, ":/bodies/beam/x|"), 5);
  EXPECT_EQ(count_of(text, ":/bodies/ball/v|"), 5);
  EXPECT_EQ(count_of(text, ":/bodies/beam/tets<"), 5);
}

// ParaView itself (its Xdmf3 readers) shows every frame of every body: run when
// pvpython is installed (Debian: python3-paraview), skipped otherwise.
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
  const fs::path listing = dir / "paraview.txt";
  const std::string command = std::string(pvpython) + " --force-offscreen-rendering '" + script.string() + "' '" +
                              fs::absolute(dir / "out.xmf").string() + "' > '" + listing.string() + "' 2> '" +
                              (dir / "paraview.err").string() + "'";
  ASSERT_EQ(std::system(command.c_str()), 0) << command << "\n" << read_text(dir / "paraview.err");

  std::string expected;
  for (const std::string reader : {"Xdmf3ReaderT", "Xdmf3ReaderS"})
    for (int k = 0; k < 3; ++k) {
      int first_entry = 0;
      for (const auto& [block, nodes, cells] : std::vector<std::tuple<int, int, int>>{{0, 5, 2}, {1, 4, 1}}) {
        double x_sum = 0, v_sum = 0;
        for (int e = first_entry; e < first_entry + 3 * nodes; ++e) {
          x_sum += x_value(k, e);
          v_sum += v_value(k, e);
        }
        first_entry += 3 * nodes;
        char line[256];
        std::snprintf(line, sizeof line, "%s %d %g %d %d %d %.6f %.6f\n", reader.c_str(), k, time_value(k), block,
                      nodes, cells, x_sum, v_sum);
        expected += line;
      }
    }
  EXPECT_EQ(read_text(listing), expected) << read_text(dir / "paraview.err");
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
  EXPECT_EQ(count_of(text, "<Attribute"), 0);
  EXPECT_EQ(count_of(text, "/v<"), 0);
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
    const int value = writer.add_series("/actuators/cable/value", 0);
    const int effector = writer.add_series("/bodies/beam/effectors/tip", 3);
    EXPECT_THROW(writer.add_series("/time", 0), std::logic_error);
    for (int k = 0; k < 1500; ++k) {  // more than one chunk
      const double scalar = 0.5 * k;
      const double row[3] = {1.0 * k, 2.0 * k, 3.0 * k};
      writer.append_series(value, &scalar);
      writer.append_series(effector, row);
    }
    MatX jacobian(3, 2);
    jacobian << 1, 2, 3, 4, 5, 6;  // row-major reading order
    writer.write_matrix("/jacobians/young", jacobian, {{"theta", "beam.young"}, {"frame", "4"}});
    EXPECT_THROW(writer.write_matrix("/jacobians/young", jacobian), std::logic_error);
    writer.set_attribute("/", "note", "hello");
    writer.set_attribute("/bodies/beam", "young", 2.5e5);
    writer.set_attribute("/bodies/beam", "young", 3.5e5);  // replaced
    writer.set_attribute("/jacobians", "frames", "last");
    EXPECT_THROW(writer.set_attribute("/calibration", "converged", 1.0), std::logic_error);
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
  EXPECT_EQ(string_attribute(h5.id, "/jacobians/young", "frame"), "4");
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

TEST(Hdf5Writer, LibraryVersion) {
  EXPECT_TRUE(std::regex_match(softdiff::io::hdf5_version(), std::regex(R"(1\.\d+\.\d+)")));
}

TEST(Xdmf, EscapesNames) {
  EXPECT_EQ(softdiff::io::xml_escape("a<b>&\"c'"), "a&lt;b&gt;&amp;&quot;c&apos;");
  const std::string text = softdiff::io::xdmf_text("R&D.h5", {{"b<1>", 4, 1}}, {0.0, 0.5}, false);
  std::string problem;
  EXPECT_TRUE(well_formed_xml(text, problem)) << problem << "\n" << text;
  EXPECT_NE(text.find("R&amp;D.h5:/bodies/b&lt;1&gt;/x"), std::string::npos);
  EXPECT_NE(text.find("<Time Value=\"0.5\"/>"), std::string::npos);
}

}  // namespace
