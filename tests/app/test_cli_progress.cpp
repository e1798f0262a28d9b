// Progress on a terminal (docs/cli.md "Progress"): simulate, control, check-grad and
// calibrate draw a bar with steps, rate and ETA on stderr when it is a terminal, none
// on a pipe or with --quiet; calibrate's line per iteration is printed as the iteration
// ends (before the next run starts). The terminal is a pseudo-terminal made by
// `script` (util-linux, in Debian's essential bsdutils).
#include <support/cli.hpp>

#include <gtest/gtest.h>

#include <filesystem>
#include <string>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_progress";

// `softdiff ARGS` with stderr on a pseudo-terminal (what it drew there in `terminal`),
// stdout to a file.
struct TtyRun {
  int code = -1;
  std::string terminal, out;
};
TtyRun run_cli_tty(const std::string& args, const fs::path& dir) {
  const auto typescript = dir / "terminal.txt", out = dir / "stdout.txt";
  const std::string inner = "cd '" + dir.string() + "' && OMP_NUM_THREADS=1 '" SOFTDIFF_CLI "' " + args + " >'" +
                            out.string() + "'";
  // -e: the command's exit code; -f: flush as written; the typescript goes to stdout.
  const std::string cmd = "script -qfec \"" + inner + "\" /dev/null >'" + typescript.string() + "' </dev/null";
  const int status = std::system(cmd.c_str());
  TtyRun r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.terminal = read_text(typescript);
  r.out = read_text(out);
  return r;
}

bool has_bar(const std::string& s) {
  return s.find(" steps/s  ETA ") != std::string::npos && s.find('\r') != std::string::npos &&
         s.find("[=") != std::string::npos;
}

std::string beam(long steps, const std::string& body_extra = "") {
  return "softdiff: 1\n"
         "simulation: {dt: 0.01, steps: " + std::to_string(steps) + "}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + (kRoot / "meshes/beam.msh").string() + "\n"
         "    material: {law: corotational, young: 2.0e5, poisson: 0.45, density: 1070}\n"
         "    fixed:\n"
         "      - group: clamp\n" + body_extra;
}

const std::string kServo =
    "    actuators:\n"
    "      - {name: pull, type: servo, nodes: {box: [0.19, -1, -1, 1, 1, 1]}, direction: [0, 1, 0], force: 0, "
    "limits: [-0.05, 0.05]}\n"
    "    effectors:\n"
    "      - {name: tip, point: [0.2, 0.01, 0.01]}\n";

// Each command: on a terminal a bar, with --quiet none; on a pipe none.
void expect_progress_only_on_terminal(const fs::path& dir, const std::string& args) {
  const std::string name = args.substr(0, args.find(' '));
  const TtyRun tty = run_cli_tty(args, dir);
  ASSERT_EQ(tty.code, 0) << tty.terminal;
  EXPECT_TRUE(has_bar(tty.terminal)) << name << " on a terminal drew:\n" << tty.terminal;
  EXPECT_EQ(tty.out.find("ETA"), std::string::npos) << "the bar is on stderr, not stdout";

  const TtyRun quiet = run_cli_tty(args + " --quiet", dir);
  ASSERT_EQ(quiet.code, 0) << quiet.terminal;
  EXPECT_EQ(quiet.terminal.find("ETA"), std::string::npos) << name << " --quiet drew:\n" << quiet.terminal;

  const CliRun pipe = run_cli(args, dir);
  ASSERT_EQ(pipe.code, 0) << pipe.err;
  EXPECT_EQ(pipe.err.find("ETA"), std::string::npos) << name << " on a pipe wrote:\n" << pipe.err;
  EXPECT_EQ(pipe.err.find('\r'), std::string::npos) << name << " on a pipe wrote:\n" << pipe.err;
}

fs::path with_scene(const std::string& name, const std::string& scene) {
  const auto dir = fresh_dir(kWork, name);
  write_text(dir / "scene.yaml", scene);
  return dir;
}

TEST(CliProgress, SimulateDrawsABarOnlyOnATerminal) {
  expect_progress_only_on_terminal(with_scene("simulate", beam(20)), "simulate scene.yaml -o out.h5 --force");
}

TEST(CliProgress, ControlDrawsABarOnlyOnATerminal) {
  expect_progress_only_on_terminal(with_scene("control", beam(10, kServo)),
                                   "control scene.yaml --target=0.2,0.02,0.01 -o c.h5 --force");
}

TEST(CliProgress, CheckGradDrawsABarOnlyOnATerminal) {
  expect_progress_only_on_terminal(with_scene("check_grad", beam(3)), "check-grad scene.yaml --steps 2 --wrt young,density");
}

TEST(CliProgress, CalibrateDrawsABarPerRunAndPrintsEachIterationAsItEnds) {
  const auto dir = with_scene("calibrate", beam(3));
  ASSERT_EQ(run_cli("simulate scene.yaml -o target.h5 --quiet", dir).code, 0);
  const std::string args = "calibrate scene.yaml --param young --init 5e4 --target target.h5 -o cal.h5 --force";
  expect_progress_only_on_terminal(dir, args);
  const TtyRun tty = run_cli_tty(args, dir);
  ASSERT_EQ(tty.code, 0) << tty.terminal;
  // A bar per run, labelled with the run's number, and one for the final run.
  const auto run1 = tty.terminal.find("run 1 [");
  const auto line0 = tty.terminal.find("softdiff: iteration 0: young = 50000");
  const auto run2 = tty.terminal.find("run 2 [");
  ASSERT_NE(run1, std::string::npos) << tty.terminal;
  ASSERT_NE(line0, std::string::npos) << tty.terminal;
  ASSERT_NE(run2, std::string::npos) << tty.terminal;
  EXPECT_NE(tty.terminal.find("final run ["), std::string::npos) << tty.terminal;
  // Iteration 0's line is out before the second run starts, on a line of its own
  // (the bar erased first).
  EXPECT_LT(run1, line0);
  EXPECT_LT(line0, run2);
  EXPECT_EQ(tty.terminal[line0 - 1], '\r') << tty.terminal;
  // On a pipe: the iteration lines, no bar.
  const CliRun pipe = run_cli(args, dir);
  ASSERT_EQ(pipe.code, 0) << pipe.err;
  EXPECT_NE(pipe.err.find("softdiff: iteration 1: young = "), std::string::npos) << pipe.err;
  EXPECT_EQ(pipe.err.find("run 1 ["), std::string::npos) << pipe.err;
}

}  // namespace
