// io::read_status, io::Hdf5Reader and io::write_hdf5_table: the HDF5 reading and the
// table writing that `softdiff sweep` and `softdiff collect` use (app/ holds no HDF5
// call). Files are written by Hdf5Writer (the real output) or read back independently
// with the HDF5 C API (tests/support/h5.hpp and the helpers below).
#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_reader.hpp>
#include <softdiff/io/hdf5_table.hpp>
#include <softdiff/io/hdf5_writer.hpp>

#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

namespace hdf5_reader_test {

namespace fs = std::filesystem;
using softdiff::VecX;
using softdiff::io::Hdf5Reader;
using softdiff::io::Hdf5Writer;
using softdiff::io::read_status;
using softdiff::io::TableColumn;
using softdiff::io::write_hdf5_table;

// A clean folder per test (tests may run in parallel processes).
fs::path test_dir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / "io_hdf5_reader" / std::string(info->name());
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// One body of 3 nodes; x of frame k, entry e: 10 k + 0.5 e (exact in binary).
constexpr int kNodes = 3;
double x_value(int frame, int entry) { return 10.0 * frame + 0.5 * entry; }

softdiff::io::WriterOptions options_for(const fs::path& file) {
  softdiff::io::WriterOptions o;
  o.file = file;
  o.command = "softdiff simulate scene.yaml";
  o.scene_yaml = "bodies: {}\n";
  o.flush_every = 1;
  return o;
}

std::vector<softdiff::io::OutputBody> one_body() {
  softdiff::io::OutputBody b;
  b.name = "beam";
  b.rest.resize(3, kNodes);
  b.rest.setZero();
  b.tets.resize(4, 1);
  b.tets << 0, 1, 2, 0;
  b.surface.resize(3, 1);
  b.surface << 0, 1, 2;
  return {b};
}

void append_frames(Hdf5Writer& writer, int count) {
  VecX x(3 * kNodes);
  for (int k = 0; k < count; ++k) {
    for (int e = 0; e < 3 * kNodes; ++e) x[e] = x_value(k, e);
    writer.append_frame(0.5 * k, x, nullptr, 0.0);
  }
}

// An output with `frames` frames finished with `status`.
void write_output(const fs::path& file, int frames, const std::string& status) {
  Hdf5Writer writer(options_for(file), one_body());
  append_frames(writer, frames);
  writer.finish(status);
}

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

// A 1-D dataset of variable-length strings, with its type checked: variable-length,
// UTF-8 (what h5py reads as str).
std::vector<std::string> read_strings(hid_t f, const std::string& path) {
  std::vector<std::string> out;
  const hid_t d = H5Dopen2(f, path.c_str(), H5P_DEFAULT);
  if (d < 0) return out;
  const hid_t type = H5Dget_type(d);
  EXPECT_EQ(H5Tget_class(type), H5T_STRING) << path;
  EXPECT_GT(H5Tis_variable_str(type), 0) << path;
  EXPECT_EQ(H5Tget_cset(type), H5T_CSET_UTF8) << path;
  const hid_t space = H5Dget_space(d);
  const auto n = static_cast<std::size_t>(H5Sget_simple_extent_npoints(space));
  std::vector<char*> texts(n, nullptr);
  if (n > 0 && H5Dread(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, texts.data()) >= 0)
    for (char* t : texts) out.emplace_back(t != nullptr ? t : "");
  if (n > 0) H5Dvlen_reclaim(type, space, H5P_DEFAULT, texts.data());
  H5Sclose(space);
  H5Tclose(type);
  H5Dclose(d);
  return out;
}

H5T_class_t type_class(hid_t f, const std::string& path) {
  const hid_t d = H5Dopen2(f, path.c_str(), H5P_DEFAULT);
  if (d < 0) return H5T_NO_CLASS;
  const hid_t type = H5Dget_type(d);
  const H5T_class_t c = H5Tget_class(type);
  H5Tclose(type);
  H5Dclose(d);
  return c;
}

// An HDF5 file made with the C API alone: a root string attribute `name` (when not
// empty) of the given kind, and nothing else.
void write_plain_h5(const fs::path& file, const std::string& name, bool fixed_length) {
  const hid_t f = H5Fcreate(file.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  ASSERT_GE(f, 0);
  if (!name.empty()) {
    const std::string value = "complete";
    const hid_t type = H5Tcopy(H5T_C_S1);
    H5Tset_size(type, fixed_length ? value.size() : H5T_VARIABLE);
    const hid_t space = H5Screate(H5S_SCALAR);
    const hid_t a = H5Acreate2(f, name.c_str(), type, space, H5P_DEFAULT, H5P_DEFAULT);
    const char* p = value.c_str();
    EXPECT_GE(fixed_length ? H5Awrite(a, type, p) : H5Awrite(a, type, &p), 0);
    H5Aclose(a);
    H5Sclose(space);
    H5Tclose(type);
  }
  H5Fclose(f);
}

// ---------------------------------------------------------------------------
// read_status

TEST(Hdf5Reader, StatusOfACompleteOutput) {
  const fs::path dir = test_dir();
  write_output(dir / "out.h5", 2, "complete");
  EXPECT_EQ(read_status(dir / "out.h5"), std::optional<std::string>("complete"));
}

TEST(Hdf5Reader, StatusOfAnInterruptedOrDivergedOutput) {
  const fs::path dir = test_dir();
  write_output(dir / "a.h5", 3, "interrupted");
  write_output(dir / "b.h5", 1, "diverged: Newton did not converge at step 1");
  EXPECT_EQ(read_status(dir / "a.h5"), std::optional<std::string>("interrupted"));
  EXPECT_EQ(read_status(dir / "b.h5"), std::optional<std::string>("diverged: Newton did not converge at step 1"));
  // An unfinished run over an existing output goes to a side file (docs/output.md).
  softdiff::io::WriterOptions o = options_for(dir / "a.h5");
  o.force = true;
  {
    Hdf5Writer writer(o, one_body());
    append_frames(writer, 1);
    writer.finish("interrupted");
  }
  EXPECT_EQ(read_status(softdiff::io::side_file_name(dir / "a.h5", "interrupted")),
            std::optional<std::string>("interrupted"));
}

TEST(Hdf5Reader, StatusOfAKilledRunIsRunning) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    auto* writer = new Hdf5Writer(options_for(file), one_body());  // never destroyed: the process dies
    append_frames(*writer, 2);
    ::_exit(0);  // no destructor, no HDF5 close: the .partial keeps "running"
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  EXPECT_FALSE(fs::exists(file));
  EXPECT_EQ(read_status(dir / "out.h5.partial"), std::optional<std::string>("running"));
}

TEST(Hdf5Reader, NoStatusForAMissingOrForeignFile) {
  const fs::path dir = test_dir();
  EXPECT_EQ(read_status(dir / "missing.h5"), std::nullopt);
  EXPECT_EQ(read_status(dir), std::nullopt) << "a folder";
  std::ofstream(dir / "text.h5") << "not an HDF5 file\n";
  EXPECT_EQ(read_status(dir / "text.h5"), std::nullopt);
  write_plain_h5(dir / "empty.h5", "", false);
  EXPECT_EQ(read_status(dir / "empty.h5"), std::nullopt) << "no status attribute";
  write_plain_h5(dir / "other.h5", "state", false);
  EXPECT_EQ(read_status(dir / "other.h5"), std::nullopt) << "another attribute only";
  // The writer's status is a variable-length string; a fixed-length one is not a
  // softdiff output's (sweep's job_status then calls the file failed).
  write_plain_h5(dir / "fixed.h5", "status", true);
  EXPECT_EQ(read_status(dir / "fixed.h5"), std::nullopt);
  // The control case of the same writer: a variable-length status is read.
  write_plain_h5(dir / "variable.h5", "status", false);
  EXPECT_EQ(read_status(dir / "variable.h5"), std::optional<std::string>("complete"));
}

// ---------------------------------------------------------------------------
// Hdf5Reader

TEST(Hdf5Reader, ReadsDatasetsGroupsAndNumericAttributesOfAnOutput) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "out.h5";
  {
    Hdf5Writer writer(options_for(file), one_body());
    append_frames(writer, 3);
    const int s = writer.add_series("/control/distance", 0, "m");
    for (const double d : {0.25, 0.125, 0.0625}) writer.append_series(s, &d);
    writer.set_attribute("/control", "young", 2.5e5);
    writer.set_attribute("/control", "note", "text, skipped");
    writer.set_attribute("/control", "iterations", std::int64_t{7});
    writer.set_attribute("/control", "converged", 1);
    writer.finish("complete");
  }
  const Hdf5Reader r(file);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r.exists("/bodies/beam/x"));
  EXPECT_FALSE(r.exists("/bodies/ball/x")) << "a missing parent group is a missing object";
  EXPECT_FALSE(r.exists("/nothing"));

  std::vector<std::size_t> shape;
  const std::vector<double> x = r.read("/bodies/beam/x", &shape);
  ASSERT_EQ(shape, (std::vector<std::size_t>{3, kNodes, 3}));
  ASSERT_EQ(x.size(), std::size_t{3 * kNodes * 3});
  for (int k = 0; k < 3; ++k)
    for (int e = 0; e < 3 * kNodes; ++e) EXPECT_EQ(x[static_cast<std::size_t>(k * 3 * kNodes + e)], x_value(k, e));
  // Integer datasets are converted to float64: the tet's node indices.
  EXPECT_EQ(r.read("/bodies/beam/tets"), (std::vector<double>{0, 1, 2, 0}));
  EXPECT_EQ(r.read("/control/distance"), (std::vector<double>{0.25, 0.125, 0.0625}));

  // Absent: empty, shape untouched.
  std::vector<std::size_t> untouched{42};
  EXPECT_TRUE(r.read("/bodies/beam/effectors/tip", &untouched).empty());
  EXPECT_EQ(untouched, std::vector<std::size_t>{42});

  EXPECT_EQ(r.members("/bodies"), std::vector<std::string>{"beam"});
  // The writer does not track creation order: by name.
  EXPECT_EQ(r.members("/bodies/beam"),
            (std::vector<std::string>{"displacement", "rest", "surface", "tets", "x"}));
  EXPECT_TRUE(r.members("/bodies/beam/effectors").empty());

  const auto attributes = r.numeric_attributes("/control");
  ASSERT_EQ(attributes.size(), 3u) << "the text attribute is skipped";
  // In the order written (HDF5 keeps a few attributes in the object header in that
  // order); the integers converted to float64.
  EXPECT_EQ(attributes[0], (std::pair<std::string, double>{"young", 2.5e5}));
  EXPECT_EQ(attributes[1], (std::pair<std::string, double>{"iterations", 7.0}));
  EXPECT_EQ(attributes[2], (std::pair<std::string, double>{"converged", 1.0}));
  EXPECT_TRUE(r.numeric_attributes("/calibration").empty());
}

TEST(Hdf5Reader, AFileThatIsNotHdf5IsNotOk) {
  const fs::path dir = test_dir();
  std::ofstream(dir / "text.h5") << "not an HDF5 file\n";
  const Hdf5Reader r(dir / "text.h5");
  EXPECT_FALSE(r.ok());
  EXPECT_FALSE(r.exists("/time"));
  EXPECT_TRUE(r.read("/time").empty());
  EXPECT_TRUE(r.members("/bodies").empty());
  EXPECT_FALSE(Hdf5Reader(dir / "missing.h5").ok());
}

// ---------------------------------------------------------------------------
// write_hdf5_table

TEST(Hdf5Table, RoundTripThroughTheCApi) {
  const fs::path dir = test_dir();
  const fs::path file = dir / "results.h5";
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const std::vector<TableColumn> columns{
      {"job", "1", std::vector<double>{0, 1, 2}},
      {"bodies.beam.material.young", "SI (the scene path's unit, docs/scene.md)", std::vector<double>{1e5, 2e5, 3e5}},
      {"status", "1", std::vector<std::string>{"complete", "failed", "missing"}},
      {"tip.x", "m", std::vector<double>{0.1, nan, -2.5e-17}},
      {"--target", "1", std::vector<std::string>{"a.csv", "", "d\xc3\xa9j\xc3\xa0.csv"}}};  // UTF-8: déjà
  std::ofstream(file) << "an older table, replaced\n";
  write_hdf5_table(file, columns);
  EXPECT_FALSE(fs::exists(dir / "results.h5.partial"));

  H5File h5(file);
  ASSERT_GE(h5.id, 0);
  EXPECT_EQ(softdiff::test::h5_string_attribute(h5.id, "/", "columns"),
            "job,bodies.beam.material.young,status,tip.x,--target");
  for (const TableColumn& c : columns) {
    EXPECT_EQ(softdiff::test::h5_shape(h5.id, "/" + c.name), std::vector<hsize_t>{3}) << c.name;
    EXPECT_EQ(softdiff::test::h5_string_attribute(h5.id, "/" + c.name, "units"), c.units) << c.name;
    if (const auto* values = std::get_if<std::vector<double>>(&c.values)) {
      EXPECT_EQ(type_class(h5.id, "/" + c.name), H5T_FLOAT) << c.name;
      const std::vector<double> back = softdiff::test::h5_read(h5.id, "/" + c.name);
      ASSERT_EQ(back.size(), values->size());
      for (std::size_t i = 0; i < back.size(); ++i) {
        if (std::isnan((*values)[i]))
          EXPECT_TRUE(std::isnan(back[i])) << c.name << "[" << i << "]";
        else
          EXPECT_EQ(back[i], (*values)[i]) << c.name << "[" << i << "]";  // float64 stores every double exactly
      }
    } else {
      EXPECT_EQ(read_strings(h5.id, "/" + c.name), std::get<std::vector<std::string>>(c.values)) << c.name;
    }
  }
  // Read back through Hdf5Reader as well (members by name: the order is the `columns` attribute's).
  const Hdf5Reader r(file);
  EXPECT_EQ(r.members("/"), (std::vector<std::string>{"--target", "bodies.beam.material.young", "job", "status",
                                                      "tip.x"}));
  EXPECT_EQ(r.read("/job"), (std::vector<double>{0, 1, 2}));
}

TEST(Hdf5Table, AFailedWriteLeavesNoFile) {
  const fs::path dir = test_dir();
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);  // the failures below are expected
  // A column name with '/' would need a group: the dataset cannot be created.
  const std::vector<TableColumn> bad{{"job", "1", std::vector<double>{0}},
                                     {"a/b", "m", std::vector<double>{1}}};
  EXPECT_THROW(write_hdf5_table(dir / "t.h5", bad), softdiff::ComputationError);
  EXPECT_FALSE(fs::exists(dir / "t.h5"));
  EXPECT_FALSE(fs::exists(dir / "t.h5.partial"));
  // A missing folder.
  try {
    write_hdf5_table(dir / "no" / "t.h5", {{"job", "1", std::vector<double>{0}}});
    ADD_FAILURE() << "no error for a missing folder";
  } catch (const softdiff::ComputationError& e) {
    EXPECT_NE(std::string(e.what()).find((dir / "no" / "t.h5").string()), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(dir / "no"));
  // Columns of different lengths are a programming error, found before any file.
  EXPECT_THROW(write_hdf5_table(dir / "u.h5", {{"a", "1", std::vector<double>{0, 1}},
                                               {"b", "1", std::vector<std::string>{"x"}}}),
               std::logic_error);
  EXPECT_FALSE(fs::exists(dir / "u.h5"));
  EXPECT_FALSE(fs::exists(dir / "u.h5.partial"));
}

}  // namespace hdf5_reader_test
