#pragma once
// Runs the softdiff executable (SOFTDIFF_CLI) and captures exit code, stdout, stderr.
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <sys/wait.h>

namespace softdiff::test {

struct CliRun {
  int code = -1;
  std::string out, err;
};

inline std::string read_text(const std::filesystem::path& p) {
  std::ifstream f(p);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

inline void write_text(const std::filesystem::path& p, const std::string& text) {
  std::filesystem::create_directories(p.parent_path());
  std::ofstream(p) << text;
}

// An empty folder `root / name` (removed and recreated).
inline std::filesystem::path fresh_dir(const std::filesystem::path& root, const std::string& name) {
  const std::filesystem::path d = root / name;
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}

// `args` is appended to the command line as is (quote paths yourself if needed).
inline CliRun run_cli(const std::string& args, const std::filesystem::path& workdir) {
  std::filesystem::create_directories(workdir);
  const auto out = workdir / "stdout.txt", err = workdir / "stderr.txt";
  const std::string cmd = "cd '" + workdir.string() + "' && OMP_NUM_THREADS=1 '" SOFTDIFF_CLI "' " + args + " >'" +
                          out.string() + "' 2>'" + err.string() + "' </dev/null";
  const int status = std::system(cmd.c_str());
  CliRun r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = read_text(out);
  r.err = read_text(err);
  return r;
}

}  // namespace softdiff::test
