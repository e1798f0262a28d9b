// What a run promises about its files holds under every failure (docs/output.md
// "Streaming and safety", docs/cli.md "Signals"): --force never replaces a complete
// file with an unfinished run, signals (SIGINT, SIGTERM, SIGHUP; a second one stops
// the step in progress) leave a valid file, a full disk is reported as such, an
// output that would overwrite an input is refused, an output that cannot fit is
// refused before the run, CHOLMOD running out of memory says so, and zero steps or
// durations get a message a person can read.
//
// The disk tests mount small tmpfs folders (root only: skipped otherwise).
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

namespace softdiff_output_safety_test {

namespace fs = std::filesystem;
using softdiff::test::CliRun;
using softdiff::test::read_text;
using softdiff::test::run_cli;
using softdiff::test::write_text;

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_output_safety";

fs::path fresh_dir(const std::string& name) { return softdiff::test::fresh_dir(kWork, name); }

std::string scene_text(const fs::path& mesh, long steps, const std::string& extra = "") {
  return "softdiff: 1\n"
         "simulation:\n"
         "  dt: 0.01\n"
         "  steps: " +
         std::to_string(steps) + "\n" + extra +
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " +
         mesh.string() +
         "\n"
         "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n"
         "    fixed:\n"
         "      - group: clamp\n";
}
const fs::path kBeam = kRoot / "meshes/beam.msh";

// The beam of meshes/beam.geo with n elements across its height (n = 16: 46529
// nodes, 245760 tetrahedra), generated once per build folder.
fs::path refined_beam(int n) {
  const fs::path mesh = kWork / ("beam_n" + std::to_string(n) + ".msh");
  if (fs::exists(mesh)) return mesh;
  fs::create_directories(kWork);
  const fs::path tmp = kWork / ("beam_n" + std::to_string(n) + ".tmp.msh");
  const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" -3 \"" + (kRoot / "meshes/beam.geo").string() +
                          "\" -setnumber n " + std::to_string(n) + " -format msh41 -o \"" + tmp.string() +
                          "\" >/dev/null 2>&1";
  if (std::system(cmd.c_str()) != 0) return {};
  fs::rename(tmp, mesh);
  return mesh;
}

// ---- HDF5 reading

std::string status_of(const fs::path& file) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) return "<cannot open>";
  const std::string value = softdiff::test::h5_string_attribute(f, "/", "status");
  H5Fclose(f);
  return value.empty() ? "<no status>" : value;
}

// Rows of a dataset (its first dimension); -1 if the file or dataset cannot be read.
long rows_of(const fs::path& file, const std::string& path) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) return -1;
  long rows = -1;
  const hid_t d = H5Dopen2(f, path.c_str(), H5P_DEFAULT);
  if (d >= 0) {
    const hid_t space = H5Dget_space(d);
    hsize_t dims[3] = {0, 0, 0};
    if (H5Sget_simple_extent_dims(space, dims, nullptr) >= 1) rows = static_cast<long>(dims[0]);
    H5Sclose(space);
    H5Dclose(d);
  }
  H5Fclose(f);
  return rows;
}

// A valid file: /time and every body's x have the same number of frames.
void expect_consistent(const fs::path& file, long frames) {
  EXPECT_EQ(rows_of(file, "/time"), frames) << file;
  EXPECT_EQ(rows_of(file, "/bodies/beam/x"), frames) << file;
  EXPECT_EQ(rows_of(file, "/solver/step_seconds"), frames) << file;
}

// ---- processes

// The CLI started in the background (stdout.txt, stderr.txt in `dir`); `prefix`
// runs before it in the same shell (e.g. "ulimit -v 600000;").
struct Background {
  pid_t pid = -1;
  fs::path dir;
};
Background start_cli(const std::string& args, const fs::path& dir, const std::string& prefix = "") {
  const std::string cmd = "cd '" + dir.string() + "' && " + prefix + " OMP_NUM_THREADS=1 exec '" SOFTDIFF_CLI "' " +
                          args + " >stdout.txt 2>stderr.txt </dev/null";
  const pid_t pid = fork();
  if (pid == 0) {
    execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  return {pid, dir};
}

// The exit code, or -signal if a signal ended it.
int wait_exit(const Background& b) {
  int status = 0;
  if (waitpid(b.pid, &status, 0) != b.pid) return -1000;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -WTERMSIG(status);
}

// Polls `condition` (every 20 ms) while the process runs; false if it ended first
// or after `limit_s` seconds (a bound against a hung test, not a timing assertion).
bool wait_until(const Background& b, const std::function<bool()>& condition, double limit_s = 600) {
  for (double waited = 0; waited < limit_s; waited += 0.02) {
    if (condition()) return true;
    int status = 0;
    if (waitpid(b.pid, &status, WNOHANG) == b.pid) return condition();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return false;
}

std::string err_of(const Background& b) { return read_text(b.dir / "stderr.txt"); }

// ---- a small tmpfs (root only)

struct Tmpfs {
  fs::path dir;
  bool mounted = false;
  Tmpfs(const fs::path& where, const std::string& size) : dir(where) {
    fs::create_directories(dir);
    const std::string cmd = "mount -t tmpfs -o size=" + size + " tmpfs '" + dir.string() + "' 2>/dev/null";
    mounted = std::system(cmd.c_str()) == 0;
  }
  ~Tmpfs() {
    if (mounted) std::system(("umount '" + dir.string() + "' 2>/dev/null").c_str());
  }
  // Fills the file system, leaving about `keep_kib` KiB free.
  void fill(long keep_kib) const {
    const fs::space_info s = fs::space(dir);
    const long kib = static_cast<long>(s.available / 1024) - keep_kib;
    if (kib > 0)
      std::system(("dd if=/dev/zero of='" + (dir / "fill").string() + "' bs=1k count=" + std::to_string(kib) +
                   " 2>/dev/null")
                      .c_str());
  }
};
#define SKIP_UNLESS_MOUNTED(t) \
  if (!(t).mounted) GTEST_SKIP() << "cannot mount a tmpfs at " << (t).dir << " (needs root / CAP_SYS_ADMIN)"

// ---- --force and signals

// A complete out.h5 of 4 frames, then a --force run of the same name stopped by
// `signal`: the complete file stays, the new frames are in out.interrupted.h5.
void check_force_keeps_complete_file(int signal, const std::string& name) {
  const auto dir = fresh_dir("force_" + name);
  write_text(dir / "scene.yaml", scene_text(kBeam, 3));
  const CliRun first = run_cli("simulate scene.yaml -o out.h5 --quiet", dir);
  ASSERT_EQ(first.code, 0) << first.err;
  ASSERT_EQ(status_of(dir / "out.h5"), "complete");

  const auto run = start_cli("simulate scene.yaml -o out.h5 --force --steps 100000 --set output.every=100", dir);
  ASSERT_TRUE(wait_until(run, [&] { return fs::exists(dir / "out.h5.partial"); })) << err_of(run);
  kill(run.pid, signal);
  const int code = wait_exit(run);
  const std::string err = err_of(run);
  EXPECT_EQ(code, 1) << err;
  EXPECT_EQ(status_of(dir / "out.h5"), "complete") << err;
  expect_consistent(dir / "out.h5", 4);
  EXPECT_TRUE(fs::exists(dir / "out.xmf"));
  const fs::path side = dir / "out.interrupted.h5";
  ASSERT_TRUE(fs::exists(side)) << err;
  EXPECT_EQ(status_of(side), "interrupted");
  EXPECT_GE(rows_of(side, "/time"), 1);
  expect_consistent(side, rows_of(side, "/time"));
  EXPECT_TRUE(fs::exists(dir / "out.interrupted.xmf"));
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
  EXPECT_NE(err.find("out.interrupted.h5"), std::string::npos) << err;
  EXPECT_NE(err.find("out.h5 is unchanged"), std::string::npos) << err;
}

TEST(OutputSafety, ForceKeepsTheCompleteFileOnSigint) { check_force_keeps_complete_file(SIGINT, "sigint"); }
TEST(OutputSafety, ForceKeepsTheCompleteFileOnSigterm) { check_force_keeps_complete_file(SIGTERM, "sigterm"); }
// Closing the terminal: SIGHUP is handled like SIGTERM (before: the process died,
// leaving a .partial that said running).
TEST(OutputSafety, ForceKeepsTheCompleteFileOnSighup) { check_force_keeps_complete_file(SIGHUP, "sighup"); }

TEST(OutputSafety, ForceKeepsTheCompleteFileWhenTheRunDiverges) {
  const auto dir = fresh_dir("force_diverged");
  write_text(dir / "scene.yaml", scene_text(kBeam, 3));
  ASSERT_EQ(run_cli("simulate scene.yaml -o out.h5 --quiet", dir).code, 0);
  // A very soft beam with a huge step: elements invert within a few steps.
  write_text(dir / "soft.yaml",
             scene_text(kBeam, 20).replace(scene_text(kBeam, 20).find("young: 1.0e6"), 12, "young: 1.0"));
  const CliRun r = run_cli("simulate soft.yaml -o out.h5 --force --dt 0.5", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(status_of(dir / "out.h5"), "complete") << r.err;
  expect_consistent(dir / "out.h5", 4);
  ASSERT_TRUE(fs::exists(dir / "out.diverged.h5")) << r.err;
  EXPECT_EQ(status_of(dir / "out.diverged.h5").rfind("diverged: ", 0), 0u);
  EXPECT_NE(r.err.find("out.diverged.h5"), std::string::npos) << r.err;
}

// Without an existing file, an interrupted run takes the output's name.
TEST(OutputSafety, InterruptedRunWithoutOldFileTakesTheName) {
  const auto dir = fresh_dir("interrupt_plain");
  write_text(dir / "scene.yaml", scene_text(kBeam, 100000, "output: {every: 100}\n"));
  const auto run = start_cli("simulate scene.yaml -o out.h5", dir);
  ASSERT_TRUE(wait_until(run, [&] { return fs::exists(dir / "out.h5.partial"); })) << err_of(run);
  kill(run.pid, SIGTERM);
  EXPECT_EQ(wait_exit(run), 1) << err_of(run);
  EXPECT_EQ(status_of(dir / "out.h5"), "interrupted") << err_of(run);
  EXPECT_FALSE(fs::exists(dir / "out.interrupted.h5"));
}

// A second signal stops the step in progress: a step of a 245760-tet beam takes
// seconds (one thread), the first SIGINT is sent during step 1 of 2 (the run says
// so), the second one ends the run before step 1 completes: the file is valid, says
// interrupted and holds frame 0 only (had step 1 completed, it would hold 2 frames).
TEST(OutputSafety, SecondSigintAbandonsTheStepInProgress) {
  const fs::path mesh = refined_beam(16);
  ASSERT_FALSE(mesh.empty()) << "gmsh could not mesh meshes/beam.geo with n = 16";
  const auto dir = fresh_dir("second_sigint");
  write_text(dir / "scene.yaml", scene_text(mesh, 2));
  const auto run = start_cli("simulate scene.yaml -o out.h5", dir);
  ASSERT_TRUE(wait_until(run, [&] { return fs::exists(dir / "out.h5.partial"); })) << err_of(run);
  std::this_thread::sleep_for(std::chrono::seconds(1));  // into step 1 (checked below by the message)
  kill(run.pid, SIGINT);
  ASSERT_TRUE(wait_until(run, [&] { return err_of(run).find("SIGINT: stopping") != std::string::npos; }))
      << err_of(run);
  ASSERT_NE(err_of(run).find("stopping after step 1 (in progress)"), std::string::npos) << err_of(run);
  kill(run.pid, SIGINT);
  const int code = wait_exit(run);
  const std::string err = err_of(run);
  EXPECT_EQ(code, 1) << err;
  EXPECT_NE(err.find("SIGINT again: stopped during step 1 (abandoned)"), std::string::npos) << err;
  EXPECT_EQ(status_of(dir / "out.h5"), "interrupted") << err;
  expect_consistent(dir / "out.h5", 1);
  EXPECT_TRUE(fs::exists(dir / "out.xmf"));
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
}

// ---- full disks

// Too little room for even the start of the file (before: the message, then a
// SIGSEGV in HDF5's exit handler on the file left half-closed).
TEST(OutputSafety, FullDiskAtCreationExitsCleanly) {
  const auto dir = fresh_dir("disk_creation");
  write_text(dir / "scene.yaml", scene_text(kBeam, 3));
  Tmpfs disk(dir / "disk", "2m");
  SKIP_UNLESS_MOUNTED(disk);
  // Almost full: the estimate (about 450 kB: 4 frames of x and the displacement, their
  // views, the XDMF files) does not fit: refused before the run.
  disk.fill(16);
  CliRun r = run_cli("simulate scene.yaml -o disk/out.h5", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("the output will take about"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5"));
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5.partial"));
  // Room for the estimate but not for the writer's reserve (the frame and the
  // close): the file cannot be created. Exit 1, nothing left, no crash.
  fs::remove(dir / "disk/fill");
  disk.fill(600);
  r = run_cli("simulate scene.yaml -o disk/out.h5", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.err.find("No space left on device"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5"));
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5.partial"));
}

// The disk fills during the run (another writer takes the space): the run stops with
// status "failed: no space left on device after frame K" in a valid file of K + 1
// frames (before: status interrupted).
TEST(OutputSafety, DiskFullDuringTheRunIsReportedAsFailed) {
  const auto dir = fresh_dir("disk_midrun");
  write_text(dir / "scene.yaml", scene_text(kBeam, 20000, "output: {every: 20}\n"));
  Tmpfs disk(dir / "disk", "80m");  // the estimate (1001 frames): about 52 MB
  SKIP_UNLESS_MOUNTED(disk);
  const auto run = start_cli("simulate scene.yaml -o disk/out.h5", dir);
  // Some frames flushed (every 10 frames), then the disk fills.
  ASSERT_TRUE(wait_until(run, [&] {
    std::error_code ec;
    return fs::file_size(dir / "disk/out.h5.partial", ec) > 600 * 1024 && !ec;
  })) << err_of(run);
  disk.fill(0);
  const int code = wait_exit(run);
  const std::string err = err_of(run);
  EXPECT_EQ(code, 1) << err;
  EXPECT_NE(err.find("No space left on device"), std::string::npos) << err;
  const fs::path out = dir / "disk/out.h5";
  ASSERT_TRUE(fs::exists(out)) << err;
  const std::string status = status_of(out);
  const std::string prefix = "failed: no space left on device after frame ";
  ASSERT_EQ(status.rfind(prefix, 0), 0u) << status << "\n" << err;
  const long last = std::stol(status.substr(prefix.size()));
  expect_consistent(out, last + 1);
  EXPECT_NE(err.find("frames 0-" + std::to_string(last) + " are in"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5.partial"));
}

// ---- the output size

TEST(OutputSafety, OutputThatCannotFitIsRefusedBeforeTheRun) {
  const auto dir = fresh_dir("too_large");
  write_text(dir / "scene.yaml", scene_text(kBeam, 3));
  Tmpfs disk(dir / "disk", "2m");
  SKIP_UNLESS_MOUNTED(disk);
  const CliRun r = run_cli("simulate scene.yaml -o disk/out.h5 --steps 10000000", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  // 10000001 frames of 1025 nodes: x and the displacement (49.2 kB) and their views
  // (1 kB) per frame, 502 GB, plus the XDMF files.
  EXPECT_NE(r.err.find("the output will take about 52"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(" GB (10000001 frames x 50.2 kB in HDF5, plus "), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("free"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5"));
  EXPECT_FALSE(fs::exists(dir / "disk/out.h5.partial"));
}

TEST(OutputSafety, LargeOutputIsAnnounced) {
  const auto dir = fresh_dir("large");
  write_text(dir / "scene.yaml", scene_text(kBeam, 3));
  if (fs::space(dir).available < 20e9) GTEST_SKIP() << "needs 20 GB free in " << dir << " for the estimate to fit";
  // 250000 frames x 50.2 kB = 12.6 GB: above the 10 GB warning; stopped at once.
  const auto run = start_cli("simulate scene.yaml -o out.h5 --steps 250000", dir);
  ASSERT_TRUE(wait_until(run, [&] { return fs::exists(dir / "out.h5.partial"); })) << err_of(run);
  kill(run.pid, SIGTERM);
  EXPECT_EQ(wait_exit(run), 1);
  EXPECT_NE(err_of(run).find("warning: the output will take about 13"), std::string::npos) << err_of(run);
  EXPECT_NE(err_of(run).find(" GB (250001 frames x 50.2 kB in HDF5"), std::string::npos) << err_of(run);
}

// ---- outputs that are inputs

TEST(OutputSafety, OutputThatIsAnInputIsRefused) {
  const auto dir = fresh_dir("input_output");
  fs::copy_file(kBeam, dir / "beam.msh");
  write_text(dir / "scene.yaml", scene_text("beam.msh", 3));
  const std::string scene_before = read_text(dir / "scene.yaml");
  const std::string mesh_before = read_text(dir / "beam.msh");
  fs::create_hard_link(dir / "beam.msh", dir / "alias.h5");
  fs::copy_file(dir / "scene.yaml", dir / "run.xmf");  // a scene whose name is out.h5's XDMF sibling
  struct Case {
    std::string args, input;
  };
  for (const Case& c : {Case{"simulate scene.yaml -o scene.yaml --force", "scene.yaml"},
                        Case{"simulate scene.yaml -o beam.msh --force", "beam.msh"},
                        Case{"simulate scene.yaml -o ./sub/../beam.msh --force", "beam.msh"},
                        Case{"simulate scene.yaml -o alias.h5 --force", "beam.msh"},
                        Case{"simulate run.xmf -o run.h5 --force", "run.xmf"}}) {
    fs::create_directories(dir / "sub");
    const CliRun r = run_cli(c.args, dir);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find("would overwrite the input file"), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.input), std::string::npos) << c.args << "\n" << r.err;
  }
  EXPECT_EQ(read_text(dir / "scene.yaml"), scene_before);
  EXPECT_EQ(read_text(dir / "beam.msh"), mesh_before);
  EXPECT_FALSE(fs::exists(dir / "run.h5"));
}

TEST(OutputSafety, CalibrateAndControlRefuseAnOutputThatIsAnInput) {
  const auto dir = fresh_dir("input_output_commands");
  write_text(dir / "scene.yaml", scene_text(kBeam, 2));
  ASSERT_EQ(run_cli("simulate scene.yaml -o target.h5 --quiet", dir).code, 0);
  const std::string target_before = read_text(dir / "target.h5");
  CliRun r = run_cli("calibrate scene.yaml --param young --target target.h5 -o target.h5 --force", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("would overwrite the input file target.h5"), std::string::npos) << r.err;
  EXPECT_EQ(read_text(dir / "target.h5"), target_before);

  std::string actuated = scene_text(kBeam, 2) +
                         "    actuators:\n"
                         "      - {name: pull, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 1, 0], "
                         "force: 0, limits: [-0.05, 0.05]}\n"
                         "    effectors:\n"
                         "      - {name: tip, point: [0.2, 0.01, 0.01]}\n";
  write_text(dir / "actuated.yaml", actuated);
  write_text(dir / "goals.csv", "time,x,y,z\n0,0.2,0.01,0.0\n");
  const std::string goals_before = read_text(dir / "goals.csv");
  r = run_cli("control actuated.yaml --target goals.csv -o goals.csv --force", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find("would overwrite the input file goals.csv"), std::string::npos) << r.err;
  EXPECT_EQ(read_text(dir / "goals.csv"), goals_before);
}

// ---- zero steps and durations

TEST(OutputSafety, ZeroStepsAndDurationsHaveReadableMessages) {
  const auto dir = fresh_dir("zero");
  write_text(dir / "scene.yaml", scene_text(kBeam, 2));
  struct Case {
    std::string args, message;
  };
  for (const Case& c : {Case{"simulate scene.yaml -o o.h5 --dt 0", "--dt: must be > 0 s, got 0"},
                        Case{"simulate scene.yaml -o o.h5 --duration 0", "--duration: must be > 0 s, got 0"},
                        Case{"simulate scene.yaml -o o.h5 --dt -1e-3", "--dt: must be > 0 s, got -1e-3"},
                        Case{"simulate scene.yaml -o o.h5 --steps 0", "--steps: must be >= 1, got 0"},
                        Case{"simulate scene.yaml -o o.h5 --steps 2.5", "--steps: must be a whole number >= 1, got '2.5'"},
                        Case{"control scene.yaml --target 0,0,0 -o o.h5 --steps 0", "--steps: must be >= 1, got 0"},
                        Case{"check-grad scene.yaml --steps 0", "--steps: must be >= 1, got 0"},
                        Case{"check-grad scene.yaml --eps 0", "--eps: must be > 0, got 0"},
                        Case{"calibrate scene.yaml --param young --target t.h5 --tolerance 0",
                             "--tolerance: must be > 0, got 0"},
                        Case{"calibrate scene.yaml --param young --target t.h5 --max-iterations 0",
                             "--max-iterations: must be >= 1, got 0"}}) {
    const CliRun r = run_cli(c.args, dir);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(r.err.find("not in range"), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_FALSE(fs::exists(dir / "o.h5"));
  }
}

// ---- out of memory

// A 245760-tet beam under a 600 MB address-space limit: the factorization cannot
// get its memory. Before: "the system matrix is not positive definite; try
// psd_projection", also in the file's status.
TEST(OutputSafety, OutOfMemoryIsReportedAsSuch) {
  const fs::path mesh = refined_beam(16);
  ASSERT_FALSE(mesh.empty()) << "gmsh could not mesh meshes/beam.geo with n = 16";
  const auto dir = fresh_dir("out_of_memory");
  write_text(dir / "scene.yaml", scene_text(mesh, 2));
  const auto run = start_cli("simulate scene.yaml -o out.h5", dir, "ulimit -v 600000 &&");
  const int code = wait_exit(run);
  const std::string err = err_of(run);
  ASSERT_EQ(code, 1) << err;
  EXPECT_EQ(err.find("not positive definite"), std::string::npos) << err;
  EXPECT_NE(err.find("out of memory"), std::string::npos) << err;
  if (fs::exists(dir / "out.h5")) {  // the file exists when memory ran out during the run
    const std::string status = status_of(dir / "out.h5");
    EXPECT_EQ(status.rfind("failed: ", 0), 0u) << status;
    EXPECT_NE(status.find("out of memory"), std::string::npos) << status;
    EXPECT_EQ(status.find("not positive definite"), std::string::npos) << status;
  }
}

}  // namespace softdiff_output_safety_test
