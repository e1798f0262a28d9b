#pragma once
// Sweep files (docs/cli.md "sweep and collect"): parsing, expansion into jobs, the job's command
// line, and the files a sweep leaves in its folder. Shared by `softdiff sweep` and
// `softdiff collect` (which re-expands the copy DIR/sweep.yaml to know every job's axes).
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace softdiff::app {

// One axis: a scene path (grid, zip) or a command-line option (args_grid), and its values
// as YAML text (scalars as written, lists and maps in flow style).
struct SweepAxis {
  enum class Kind { grid, zip, args } kind = Kind::grid;
  std::string name;                 // bodies.trunk.material.young, --target
  std::vector<std::string> values;  // the value of the --set (KEY=VALUE) or of the option
  std::vector<std::string> labels;  // the values as collect's table shows them (unquoted)
  int line = 0, column = 0;         // of the axis' key in the sweep file
};

struct SweepPlot {
  std::string x, y, value;  // axis names (x, y) and a result column (value)
};

struct SweepDesc {
  std::filesystem::path file;   // the sweep file
  std::string text;             // its text (copied to DIR/sweep.yaml)
  std::filesystem::path scene;  // absolute
  std::string command;          // simulate | calibrate | control
  std::vector<std::string> args;
  std::vector<SweepAxis> axes;  // grid axes (file order), zip axes, args_grid axes
  std::optional<SweepPlot> plot;
};

struct SweepJob {
  long id = 0;
  std::vector<std::size_t> index;  // per axis: the index of its value (zip axes share one)
  std::vector<std::string> sets;   // KEY=VALUE of the grid and zip axes
  std::vector<std::string> args;   // args, then the args_grid options
};

// Parses and checks the file's structure (keys, types, lengths); throws InputError
// `FILE:LINE:COL: PATH: message`. The scene must exist unless `need_scene` is false
// (collect reads a copy of the sweep file that may sit elsewhere).
SweepDesc load_sweep(const std::filesystem::path& file, bool need_scene = true);
// Same, from text (DIR/sweep.yaml): `file` names it in messages and places the scene.
SweepDesc parse_sweep(const std::string& text, const std::filesystem::path& file, bool need_scene);

// Grid order: axes vary like nested loops in their order, the last fastest; the zip
// axes form one loop.
std::vector<SweepJob> expand_sweep(const SweepDesc& sweep);

// The job's softdiff arguments, without the program: COMMAND SCENE --set ... ARGS
// --threads T --quiet --json --force -o DIR/<id>.h5 (threads <= 0: none added; an
// explicit --threads in the job's args is kept).
std::vector<std::string> job_arguments(const SweepDesc& sweep, const SweepJob& job, const std::filesystem::path& dir,
                                       int threads);
// The job's line of DIR/jobs.txt: a POSIX shell command that runs from the sweep
// file's folder, writes DIR/<id>.json (stdout), DIR/<id>.log (stderr) and
// DIR/<id>.exit ("EXIT_CODE START END", seconds since the epoch), and exits with
// softdiff's exit code.
std::string job_line(const std::filesystem::path& program, const SweepDesc& sweep, const SweepJob& job,
                     const std::filesystem::path& dir, int threads);
bool has_option(const std::vector<std::string>& args, const std::string& name);

std::string shell_quote(const std::string& s);

// DIR/<id>.<ext>
std::filesystem::path job_file(const std::filesystem::path& dir, long id, const std::string& ext);

// complete | interrupted | diverged | failed | missing: the job's status by its files
// (DIR/<id>.h5, else a side file <id>.interrupted.h5 ... or <id>.h5.partial), from
// their `status` attribute (io::read_status).
std::string job_status(const std::filesystem::path& dir, long id, std::filesystem::path* found = nullptr);

// CPUs this process may run on (sched_getaffinity), at least 1.
int available_cores();

}  // namespace softdiff::app
