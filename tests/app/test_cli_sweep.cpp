// softdiff sweep / collect (docs/cli.md "sweep and collect"): the expansion of a sweep file into
// jobs (grid order, zip, args_grid), the validation of every job before anything runs
// (exit 2 naming the job, nothing written), a real GNU parallel run of a small sweep
// (2 steps of the shipped beam per job) whose results equal the same commands run
// directly, a job that fails without stopping the others, --resume, and collect's
// table. The real Slurm run is tests/app/sweep_slurm.sh.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

namespace softdiff_sweep_test {

namespace fs = std::filesystem;
using softdiff::test::CliRun;
using softdiff::test::read_text;
using softdiff::test::run_cli;
using softdiff::test::write_text;

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_sweep";

fs::path fresh_dir(const std::string& name) { return softdiff::test::fresh_dir(kWork, name); }

// The shipped beam (1025 nodes), clamped; 2 steps of 10 ms by default.
void write_scene(const fs::path& dir) {
  write_text(dir / "beam.yaml", "softdiff: 1\n"
                                "simulation: {dt: 0.01, steps: 2}\n"
                                "bodies:\n"
                                "  - name: beam\n"
                                "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
                                "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n"
                                "    fixed:\n"
                                "      - group: clamp\n"
                                "    effectors:\n"
                                "      - {name: tip, point: [0.2, 0.01, 0.01]}\n"
                                "output: {fields: [x, effectors]}\n");
}

std::vector<std::string> lines(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  std::string l;
  while (std::getline(in, l))
    if (!l.empty()) out.push_back(l);
  return out;
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::vector<std::string> csv_fields(const std::string& line) {
  std::vector<std::string> f;
  std::stringstream in(line);
  std::string x;
  while (std::getline(in, x, ',')) f.push_back(x);
  if (!line.empty() && line.back() == ',') f.push_back("");
  return f;
}

std::string attribute(const fs::path& h5, const std::string& name) {
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  const hid_t f = H5Fopen(h5.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0) return "(no file " + h5.string() + ")";
  const std::string s = softdiff::test::h5_string_attribute(f, "/", name);
  H5Fclose(f);
  return s;
}

std::vector<double> dataset(const fs::path& h5, const std::string& path) {
  const hid_t f = H5Fopen(h5.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  EXPECT_GE(f, 0) << h5;
  if (f < 0) return {};
  std::vector<double> v = softdiff::test::h5_read(f, path);
  H5Fclose(f);
  return v;
}

TEST(CliSweep, ExpandsInGridOrderWithZipAndArgsGrid) {
  const fs::path dir = fresh_dir("expand");
  write_scene(dir);
  // Loops: young (2), then the zip pair (2), then --steps (2): 8 jobs, the last varying fastest.
  write_text(dir / "s.yaml", "softdiff_sweep: 1\n"
                             "scene: beam.yaml\n"
                             "command: simulate\n"
                             "grid:\n"
                             "  bodies.beam.material.young: [1.0e6, 2.0e6]\n"
                             "zip:\n"
                             "  bodies.beam.material.poisson: [0.3, 0.4]\n"
                             "  bodies.beam.material.density: [1000, 1100]\n"
                             "args_grid:\n"
                             "  --steps: [\"1\", \"2\"]\n");
  const CliRun r = run_cli("sweep s.yaml -o out --jobs 2 --dry-run", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_FALSE(fs::exists(dir / "out")) << "--dry-run writes nothing";
  const auto jobs = lines(r.out);
  ASSERT_EQ(jobs.size(), 8u) << r.out;
  const char* young[] = {"1.0e6", "2.0e6"};
  const char* poisson[] = {"0.3", "0.4"};
  const char* density[] = {"1000", "1100"};
  for (int id = 0; id < 8; ++id) {
    const std::string& j = jobs[static_cast<std::size_t>(id)];
    const int y = id / 4, z = (id / 2) % 2, s = id % 2;
    EXPECT_TRUE(contains(j, std::string("bodies.beam.material.young=") + young[y])) << id << ": " << j;
    EXPECT_TRUE(contains(j, std::string("bodies.beam.material.poisson=") + poisson[z])) << id << ": " << j;
    EXPECT_TRUE(contains(j, std::string("bodies.beam.material.density=") + density[z])) << id << ": " << j;
    EXPECT_TRUE(contains(j, " --steps=" + std::to_string(s + 1) + " ")) << id << ": " << j;
    EXPECT_TRUE(contains(j, (dir / "out" / (std::to_string(id) + ".h5")).string())) << id << ": " << j;
    // --jobs 2 on this machine: cores / 2 threads each (at least 1), for OpenMP and OpenBLAS.
    EXPECT_TRUE(contains(j, " --threads ")) << j;
    EXPECT_TRUE(contains(j, "OPENBLAS_NUM_THREADS=")) << j;
  }
}

TEST(CliSweep, SlurmDryRunPrintsTheArrayScript) {
  const fs::path dir = fresh_dir("slurm_dry");
  write_scene(dir);
  write_text(dir / "s.yaml", "softdiff_sweep: 1\nscene: beam.yaml\ncommand: simulate\n"
                             "grid: {bodies.beam.material.young: [1.0e6, 2.0e6, 3.0e6]}\n");
  const CliRun r = run_cli("sweep s.yaml -o out --slurm --jobs 2 --slurm-opt=--partition=short --dry-run", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(contains(r.out, "#SBATCH --array=0-2%2\n")) << r.out;
  EXPECT_TRUE(contains(r.out, "#SBATCH --cpus-per-task=1\n")) << r.out;
  EXPECT_TRUE(contains(r.out, "#SBATCH --partition=short\n")) << r.out;
  EXPECT_TRUE(contains(r.out, "SLURM_ARRAY_TASK_ID + 1")) << r.out;
  EXPECT_FALSE(fs::exists(dir / "out"));
}

TEST(CliSweep, EveryJobIsValidatedBeforeAnythingRuns) {
  const fs::path dir = fresh_dir("validate");
  write_scene(dir);
  struct Case {
    std::string body;     // after the common head
    std::string message;  // part of stderr
  };
  const std::string head = "softdiff_sweep: 1\nscene: beam.yaml\ncommand: simulate\n";
  const std::vector<Case> cases = {
      // A bad value in the third job: named with its axes.
      {"grid: {bodies.beam.material.young: [1.0e6, 2.0e6, -5]}\n",
       "job 2 (bodies.beam.material.young=-5): --set: bodies[0].material.young: must be > 0"},
      {"grid: {bodies.beam.material.yuong: [1.0e6]}\n", "job 0 (bodies.beam.material.yuong=1.0e6): --set bodies.beam.material.yuong"},
      {"args: [\"--steps\", \"0\"]\n", "job 0: --steps: must be >= 1, got 0"},
      {"args_grid: {--dt: [\"0.01\", \"x\"]}\n", "job 1 (--dt=x): --dt: must be a number of s, got 'x'"},
      {"grid: {bodies.beam.material.young: 1.0e6}\n", "s.yaml:4:8: grid.bodies.beam.material.young: must be a non-empty list"},
      {"zip: {bodies.beam.material.young: [1, 2], bodies.beam.material.poisson: [0.3]}\n",
       "zip.bodies.beam.material.poisson: zip axes must have equal lengths"},
      {"gird: {}\n", "s.yaml:4:1: gird: unknown key; did you mean 'grid'?"},
      {"args: [\"-o\", \"x.h5\"]\n", "-o is set by the sweep"},
      {"plot: {x: a, y: b, value: tip.y}\n", "plot.x: 'a' is not an axis"},
  };
  for (const auto& c : cases) {
    write_text(dir / "s.yaml", head + c.body);
    const CliRun r = run_cli("sweep s.yaml -o out", dir);
    EXPECT_EQ(r.code, 2) << c.body << r.err;
    EXPECT_TRUE(contains(r.err, c.message)) << c.body << "\nexpected: " << c.message << "\ngot: " << r.err;
    EXPECT_FALSE(fs::exists(dir / "out")) << c.body << ": an invalid sweep writes nothing";
  }
  write_text(dir / "s.yaml", "softdiff_sweep: 1\nscene: nowhere.yaml\ncommand: simulate\n");
  const CliRun r = run_cli("sweep s.yaml -o out", dir);
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(contains(r.err, "s.yaml:2:8: scene: no such file: " + (dir / "nowhere.yaml").string())) << r.err;
}

// A real GNU parallel run: 4 jobs (young x the body's scale), 2 at a time. Job 3
// scales the beam to 20 m, which --strict refuses when the job runs (the plausibility
// check needs the mesh: not part of the sweep's validation): it fails with exit 2
// and its message while the others complete.
TEST(CliSweep, ParallelRunsTheJobsResumesAndCollects) {
  const fs::path dir = fresh_dir("parallel");
  write_scene(dir);
  write_text(dir / "s.yaml", "softdiff_sweep: 1\n"
                             "scene: beam.yaml\n"
                             "command: simulate\n"
                             "args: [\"--strict\"]\n"
                             "grid:\n"
                             "  bodies.beam.material.young: [1.0e6, 2.0e6]\n"
                             "  bodies.beam.mesh_scale: [1, 100]\n"
                             "plot: {x: bodies.beam.mesh_scale, y: bodies.beam.material.young, value: tip.z}\n");
  CliRun r = run_cli("sweep s.yaml -o out --jobs 2", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  const fs::path out = dir / "out";
  ASSERT_EQ(lines(read_text(out / "jobs.txt")).size(), 4u);
  EXPECT_EQ(lines(read_text(out / "joblog.txt")).size(), 5u) << "parallel's joblog: a header and 4 jobs";
  for (int id : {0, 2}) EXPECT_EQ(attribute(out / (std::to_string(id) + ".h5"), "status"), "complete") << id;
  EXPECT_FALSE(fs::exists(out / "1.h5"));
  EXPECT_FALSE(fs::exists(out / "3.h5"));
  EXPECT_TRUE(contains(r.err, "2 of 4 jobs complete")) << r.err;
  EXPECT_TRUE(contains(r.err, "job 1 (bodies.beam.material.young=1.0e6, bodies.beam.mesh_scale=100): missing, exit 2: "
                              "softdiff: error:")) << r.err;
  EXPECT_TRUE(contains(r.err, "implausible")) << r.err;

  // The job's result equals the same command run directly with the same --threads.
  const auto job0 = lines(read_text(out / "jobs.txt"))[0];
  const auto t = job0.find("--threads ");
  ASSERT_NE(t, std::string::npos);
  const std::string threads = job0.substr(t + 10, job0.find(' ', t + 10) - t - 10);
  // (OpenBLAS's threads too, as the job line sets them.)
  ::setenv("OPENBLAS_NUM_THREADS", threads.c_str(), 1);
  r = run_cli("simulate beam.yaml --strict --set bodies.beam.material.young=1.0e6 --set bodies.beam.mesh_scale=1 --threads " +
                  threads + " -o direct.h5 --quiet",
              dir);
  ::unsetenv("OPENBLAS_NUM_THREADS");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(dataset(out / "0.h5", "/bodies/beam/x"), dataset(dir / "direct.h5", "/bodies/beam/x"));

  // collect: a row per job, the failed ones included; exit 1 (not every job complete).
  r = run_cli("collect out", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  const auto table = lines(read_text(out / "results.csv"));
  ASSERT_EQ(table.size(), 5u);
  const auto head = csv_fields(table[0]);
  const std::vector<std::string> first{"job", "bodies.beam.material.young", "bodies.beam.mesh_scale", "status", "exit_code",
                                       "wall_s"};
  ASSERT_GE(head.size(), first.size() + 4);
  EXPECT_EQ(std::vector<std::string>(head.begin(), head.begin() + 6), first);
  const auto col = [&](const std::string& name) {
    return static_cast<std::size_t>(std::find(head.begin(), head.end(), name) - head.begin());
  };
  for (const char* c : {"ms_per_step", "max_displacement", "tip.x", "tip.y", "tip.z"})
    EXPECT_LT(col(c), head.size()) << c << " in " << table[0];
  const auto row0 = csv_fields(table[1]), row1 = csv_fields(table[2]);
  EXPECT_EQ(row0[col("status")], "complete");
  EXPECT_EQ(row0[col("exit_code")], "0");
  EXPECT_EQ(row1[col("status")], "missing");
  EXPECT_EQ(row1[col("exit_code")], "2");
  // The table's tip.z is the output's last effector row, printed with 17 digits.
  const std::vector<double> tip = dataset(out / "0.h5", "/bodies/beam/effectors/tip");
  ASSERT_EQ(tip.size(), 9u);
  EXPECT_EQ(std::stod(row0[col("tip.z")]), tip[8]);
  EXPECT_TRUE(fs::exists(out / "results.h5"));
  EXPECT_EQ(attribute(out / "results.h5", "columns").substr(0, 6), "job,bo");
  EXPECT_TRUE(fs::exists(out / "results.png")) << r.err;

  // Without --resume the folder is refused; with it only the jobs not complete run
  // (here: they fail again, the complete outputs are untouched).
  r = run_cli("sweep s.yaml -o out --jobs 2", dir);
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(contains(r.err, "holds a sweep already (jobs.txt); --resume continues it")) << r.err;
  const auto before = fs::last_write_time(out / "0.h5");
  r = run_cli("sweep s.yaml -o out --jobs 2 --resume", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(lines(read_text(out / "run.txt")).size(), 2u) << "jobs 1 and 3 only";
  EXPECT_TRUE(contains(r.err, "0 of 2 jobs complete")) << r.err;
  EXPECT_EQ(fs::last_write_time(out / "0.h5"), before);

  // A job whose output is gone (or not complete) runs again: job 2's file removed.
  fs::remove(out / "2.h5");
  write_text(dir / "s2.yaml", read_text(dir / "s.yaml"));
  r = run_cli("sweep s.yaml -o out --jobs 1 --resume", dir);
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_EQ(attribute(out / "2.h5", "status"), "complete");
  EXPECT_EQ(lines(read_text(out / "run.txt")).size(), 3u) << "jobs 1, 2 and 3";

  // A changed sweep file cannot resume the folder (its job ids would mean other jobs).
  write_text(dir / "s.yaml", read_text(dir / "s2.yaml") + "# changed\n");
  r = run_cli("sweep s.yaml -o out --resume", dir);
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(contains(r.err, "differs from s.yaml")) << r.err;
}

// control through a sweep: a goal with a leading minus as an args_grid value (one
// word, --target=-...), and collect's final_distance equal to the output's last
// /control/distance.
TEST(CliSweep, ControlGoalsAndTheirFinalDistance) {
  const fs::path dir = fresh_dir("control");
  write_text(dir / "c.yaml", "softdiff_sweep: 1\n"
                             "scene: " + (kRoot / "configs/trunk.yaml").string() + "\n"
                             "command: control\n"
                             "args: [\"--steps\", \"2\"]\n"
                             "args_grid:\n"
                             "  --target: [\"-0.0305,-0.1481,0.0945\", \"0,-0.15,0.1\"]\n");
  CliRun r = run_cli("sweep c.yaml -o out --jobs 2", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  r = run_cli("collect out", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto table = lines(read_text(dir / "out/results.csv"));
  ASSERT_EQ(table.size(), 3u);
  EXPECT_EQ(table[0].substr(0, 21), "job,--target,status,e");
  EXPECT_TRUE(contains(table[1], "0,\"-0.0305,-0.1481,0.0945\",complete,0,")) << table[1];
  for (int id : {0, 1}) {
    const std::vector<double> distance = dataset(dir / "out" / (std::to_string(id) + ".h5"), "/control/distance");
    ASSERT_EQ(distance.size(), 3u);
    EXPECT_EQ(std::stod(table[static_cast<std::size_t>(id) + 1].substr(table[static_cast<std::size_t>(id) + 1].rfind(',') + 1)),
              distance.back())
        << table[0];
  }
}

// calibrate through a sweep: collect's identified value, final_cost, converged and
// iterations are the /calibration attributes of each job's output.
TEST(CliSweep, CalibrationResultsAreTheOutputsAttributes) {
  const fs::path dir = fresh_dir("calibrate");
  write_scene(dir);
  CliRun r = run_cli("simulate beam.yaml --set bodies.beam.material.young=2e5 -o target.h5 --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  write_text(dir / "c.yaml", "softdiff_sweep: 1\nscene: beam.yaml\ncommand: calibrate\n"
                             "args: [\"--param\", \"young\", \"--target\", \"target.h5\"]\n"
                             "args_grid: {--init: [\"1e5\", \"4e5\"]}\n");
  r = run_cli("sweep c.yaml -o out --jobs 2", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  r = run_cli("collect out", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto table = lines(read_text(dir / "out/results.csv"));
  ASSERT_EQ(table.size(), 3u);
  const auto head = csv_fields(table[0]);
  const auto col = [&](const std::string& name) {
    const auto it = std::find(head.begin(), head.end(), name);
    EXPECT_NE(it, head.end()) << name << " in " << table[0];
    return static_cast<std::size_t>(it - head.begin());
  };
  for (int id : {0, 1}) {
    const auto row = csv_fields(table[static_cast<std::size_t>(id) + 1]);
    const fs::path h5 = dir / "out" / (std::to_string(id) + ".h5");
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    const hid_t f = H5Fopen(h5.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    ASSERT_GE(f, 0) << h5;
    for (const char* name : {"young", "final_cost", "converged", "iterations"})
      EXPECT_EQ(std::stod(row[col(name)]), softdiff::test::h5_number_attribute(f, "/calibration", name)) << name;
    H5Fclose(f);
    EXPECT_NEAR(std::stod(row[col("young")]) / 2e5, 1.0, 1e-6) << table[static_cast<std::size_t>(id) + 1];
  }
}

// Ctrl-C: SIGINT to the sweep's process group (as a terminal sends it) stops the
// running jobs (status interrupted), GNU parallel starts no more, and the sweep
// reports them and exits 1. 3 jobs of 400 beam steps (tens of seconds each), 2 at a time.
TEST(CliSweep, SigintStopsTheJobsAndTheSweepReports) {
  const fs::path dir = fresh_dir("sigint");
  write_scene(dir);
  write_text(dir / "s.yaml", "softdiff_sweep: 1\nscene: beam.yaml\ncommand: simulate\nargs: [\"--steps\", \"400\"]\n"
                             "grid: {bodies.beam.material.young: [1.0e6, 2.0e6, 3.0e6]}\n");
  const std::string cmd = "cd '" + dir.string() + "' && exec '" SOFTDIFF_CLI "' sweep s.yaml -o out --jobs 2 "
                          ">stdout.txt 2>stderr.txt </dev/null";
  const pid_t pid = fork();
  if (pid == 0) {
    setpgid(0, 0);  // its own process group, as a shell's foreground job
    execl("/bin/sh", "sh", "-c", cmd.c_str(), static_cast<char*>(nullptr));
    _exit(127);
  }
  ASSERT_GT(pid, 0);
  setpgid(pid, pid);
  // Both running jobs have written a frame (their .partial exists); a bound of 120 s
  // against a hung test, not a timing assertion.
  bool running = false;
  for (int i = 0; i < 6000 && !running; ++i) {
    running = fs::exists(dir / "out/0.h5.partial") && fs::exists(dir / "out/1.h5.partial");
    if (!running) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_TRUE(running) << read_text(dir / "stderr.txt");
  kill(-pid, SIGINT);
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 1);
  const std::string err = read_text(dir / "stderr.txt");
  EXPECT_TRUE(contains(err, "parallel stopped (exit")) << err;
  EXPECT_TRUE(contains(err, "softdiff sweep --resume runs the jobs not complete")) << err;
  for (int id : {0, 1}) {
    EXPECT_EQ(attribute(dir / "out" / (std::to_string(id) + ".h5"), "status"), "interrupted") << id;
    EXPECT_TRUE(contains(err, "job " + std::to_string(id) + " (bodies.beam.material.young=")) << err;
  }
  EXPECT_FALSE(fs::exists(dir / "out/2.h5")) << "job 2 never started";
}

TEST(CliSweep, CollectNeedsASweepFolder) {
  const fs::path dir = fresh_dir("collect_bad");
  CliRun r = run_cli("collect nowhere", dir);
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(contains(r.err, "nowhere: not a folder")) << r.err;
  fs::create_directories(dir / "empty");
  r = run_cli("collect empty", dir);
  EXPECT_EQ(r.code, 2);
  EXPECT_TRUE(contains(r.err, "empty: holds no sweep")) << r.err;
  EXPECT_TRUE(fs::is_empty(dir / "empty"));
}

}  // namespace softdiff_sweep_test
