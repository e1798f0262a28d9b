// softdiff sweep SWEEP.yaml: expand a sweep into jobs, validate every job, and run them
// through GNU parallel (locally) or a Slurm job array (docs/cli.md "sweep and collect").
#include "commands.hpp"
#include "common.hpp"
#include "sweep.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/io/scene.hpp>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <thread>

extern char** environ;

namespace softdiff::app {
namespace {

namespace fs = std::filesystem;

// The job as a person reads it in a message: "job 3 (bodies.trunk.material.young=9e5, --target=b.h5)".
std::string job_name(const SweepDesc& s, const SweepJob& j) {
  std::string axes;
  for (std::size_t a = 0; a < s.axes.size(); ++a)
    axes += (a ? ", " : "") + s.axes[a].name + "=" + s.axes[a].labels[j.index[a]];
  return "job " + std::to_string(j.id) + (axes.empty() ? "" : " (" + axes + ")");
}

// Parses the job's arguments with the command's own options and loads the scene with
// its --set values: everything the command would refuse before it starts. Runs in
// the sweep file's folder (where the job runs: relative paths in args resolve there).
void validate_job(const SweepDesc& s, const SweepJob& job, const fs::path& dir) {
  std::vector<std::string> words{"softdiff"};
  for (auto& w : job_arguments(s, job, dir, 1)) words.push_back(w);
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  CLI::App app{"", "softdiff"};
  app.require_subcommand(1);
  SimulateOptions sim;
  CalibrateOptions cal;
  ControlOptions con;
  std::vector<std::string>* sets = nullptr;
  CLI::App* sub = app.add_subcommand(s.command);
  if (s.command == "simulate") add_simulate(*sub, sim), sets = &sim.set;
  if (s.command == "calibrate") add_calibrate(*sub, cal), sets = &cal.set;
  if (s.command == "control") add_control(*sub, con), sets = &con.set;
  const std::string where = s.file.string() + ": " + job_name(s, job) + ": ";
  try {
    app.parse(static_cast<int>(argv.size()), argv.data());
  } catch (const CLI::ParseError& e) {
    throw InputError(where + e.what());
  }
  std::vector<std::string> overrides = *sets;
  if (s.command == "simulate" && sim.steps) overrides.push_back("simulation.steps=" + std::to_string(*sim.steps));
  try {
    (void)io::load_scene(s.scene, overrides);
  } catch (const InputError& e) {
    throw InputError(where + e.what());
  }
}

// "0-3,5,7-9": Slurm's --array list of the ids.
std::string id_ranges(const std::vector<long>& ids) {
  std::string out;
  for (std::size_t i = 0; i < ids.size();) {
    std::size_t j = i;
    while (j + 1 < ids.size() && ids[j + 1] == ids[j] + 1) ++j;
    out += (out.empty() ? "" : ",") + std::to_string(ids[i]) + (j > i ? "-" + std::to_string(ids[j]) : "");
    i = j + 1;
  }
  return out;
}

// The program on PATH, or "" (what `command -v` finds).
std::string find_program(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::stringstream in(path ? path : "/usr/bin:/bin");
  std::string d;
  while (std::getline(in, d, ':')) {
    const fs::path p = fs::path(d.empty() ? "." : d) / name;
    if (::access(p.c_str(), X_OK) == 0) return p.string();
  }
  return "";
}

// Runs argv, stdout captured into `out` (when given); returns the exit code (-1: it
// could not start; 128+N: killed by signal N).
int run_program(const std::vector<std::string>& args, std::string* out,
                const std::function<void()>& while_waiting = {}) {
  std::vector<std::string> words = args;
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  argv.push_back(nullptr);
  int pipe_fd[2] = {-1, -1};
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  if (out) {
    if (::pipe(pipe_fd) != 0) return -1;
    posix_spawn_file_actions_adddup2(&actions, pipe_fd[1], STDOUT_FILENO);
    posix_spawn_file_actions_addclose(&actions, pipe_fd[0]);
    posix_spawn_file_actions_addclose(&actions, pipe_fd[1]);
  }
  posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
  pid_t pid = -1;
  const int rc = posix_spawnp(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (out) {
    ::close(pipe_fd[1]);
    if (rc == 0) {
      char buf[4096];
      ssize_t n;
      while ((n = ::read(pipe_fd[0], buf, sizeof buf)) > 0 || (n < 0 && errno == EINTR))
        if (n > 0) out->append(buf, static_cast<std::size_t>(n));
    }
    ::close(pipe_fd[0]);
  }
  if (rc != 0) return -1;
  int status = 0;
  for (;;) {
    const pid_t w = ::waitpid(pid, &status, while_waiting ? WNOHANG : 0);
    if (w == pid) break;
    if (w < 0 && errno != EINTR) return -1;
    if (w == 0) {
      while_waiting();
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
  }
  return WIFEXITED(status) ? WEXITSTATUS(status) : WIFSIGNALED(status) ? 128 + WTERMSIG(status) : -1;
}

void write_file(const fs::path& p, const std::string& text) {
  std::ofstream f(p);
  f << text;
  if (!f) throw ComputationError(p.string() + ": cannot write: " + std::strerror(errno));
}

std::string read_file(const fs::path& p) {
  std::ifstream f(p);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// The last non-empty line of a job's stderr (its error message).
std::string last_line(const std::string& text) {
  std::stringstream in(text);
  std::string line, last;
  while (std::getline(in, line)) {
    const auto cr = line.rfind('\r');  // a progress bar's redraws
    if (cr != std::string::npos) line = line.substr(cr + 1);
    if (line.find_first_not_of(" \t") != std::string::npos) last = line;
  }
  return last;
}

// --cpus-per-task=K / -c K / -cK among the --slurm-opt values (0: not given).
int slurm_cpus(const std::vector<std::string>& opts) {
  int cpus = 0;
  for (const auto& o : opts) {
    std::istringstream in(o);
    std::string a;
    std::vector<std::string> w;
    while (in >> a) w.push_back(a);
    for (std::size_t i = 0; i < w.size(); ++i) {
      std::string v;
      if (w[i].rfind("--cpus-per-task=", 0) == 0) v = w[i].substr(16);
      else if ((w[i] == "-c" || w[i] == "--cpus-per-task") && i + 1 < w.size()) v = w[i + 1];
      else if (w[i].rfind("-c", 0) == 0 && w[i].size() > 2 && std::isdigit(static_cast<unsigned char>(w[i][2]))) v = w[i].substr(2);
      if (!v.empty()) {
        char* end = nullptr;
        const long k = std::strtol(v.c_str(), &end, 10);
        if (*end != '\0' || k < 1) throw InputError("--slurm-opt " + o + ": --cpus-per-task must be a whole number >= 1");
        cpus = static_cast<int>(k);
      }
    }
  }
  return cpus;
}

}  // namespace

void add_sweep(CLI::App& app, SweepOptions& o) {
  app.add_option("sweep", o.file, "Sweep file (YAML, docs/cli.md \"sweep and collect\")")->required()->check(CLI::ExistingFile);
  app.add_option("-o,--output", o.dir, "Output folder (default: the sweep file's stem in the current folder)");
  app.add_option("--jobs", o.jobs,
                 "Jobs at a time (default: one per core); each job gets cores / jobs threads (--threads)")
      ->check(positive_integer());
  app.add_flag("--resume", o.resume, "Skip the jobs whose output DIR/<job>.h5 has status complete");
  app.add_flag("--dry-run", o.dry_run, "Validate, then print the job list (or the sbatch script) and run nothing");
  auto* slurm = app.add_flag("--slurm", o.slurm, "Submit a Slurm job array (sbatch) instead of running locally");
  app.add_option("--slurm-opt", o.slurm_opts, "An sbatch option for the script, e.g. --slurm-opt=--partition=short (repeatable)")
      ->needs(slurm)
      ->allow_extra_args(false);
  app.add_flag("--quiet", o.quiet, "No progress bar, no summary unless a job failed");
}

int run_sweep(const SweepOptions& o) {
  const SweepDesc sweep = load_sweep(o.file);
  const std::vector<SweepJob> jobs = expand_sweep(sweep);
  const fs::path dir = fs::absolute(o.dir.empty() ? fs::path(o.file).stem() : fs::path(o.dir)).lexically_normal();
  const int cores = available_cores();

  // Jobs at a time and threads per job: jobs x threads <= cores (docs/cli.md "sweep and collect").
  int threads = 1;
  long at_once = o.jobs ? *o.jobs : 0;
  if (o.slurm) {
    const int cpus = slurm_cpus(o.slurm_opts);
    threads = cpus > 0 ? cpus : 1;
  } else {
    if (at_once == 0) at_once = cores;
    threads = std::max<int>(1, static_cast<int>(cores / at_once));
    if (at_once > cores)
      warn("--jobs " + std::to_string(at_once) + " is more than the " + std::to_string(cores) +
           " cores: the jobs share them (1 thread each)");
  }
  for (const auto& j : jobs)
    if (has_option(j.args, "--threads") && !o.quiet) {
      note("the sweep's args set --threads: kept as given (jobs x threads may exceed the cores)");
      break;
    }

  // 1. Every job is checked before anything runs or is written.
  {
    const fs::path cwd = fs::current_path();
    fs::current_path(fs::absolute(sweep.file).parent_path());
    try {
      for (const auto& j : jobs) validate_job(sweep, j, dir);
    } catch (...) {
      fs::current_path(cwd);
      throw;
    }
    fs::current_path(cwd);
  }
  std::error_code ec;
  const bool dir_exists = fs::exists(dir, ec);
  if (dir_exists && !fs::is_directory(dir, ec)) throw InputError(dir.string() + ": exists and is not a folder; choose another -o");
  if (dir_exists && fs::exists(dir / "jobs.txt", ec)) {
    if (!o.resume)
      throw InputError(dir.string() + ": holds a sweep already (jobs.txt); --resume continues it, or choose another -o");
    if (read_file(dir / "sweep.yaml") != sweep.text)
      throw InputError(dir.string() + "/sweep.yaml: differs from " + o.file +
                       ": --resume continues the same sweep only (its job ids would change); choose another -o");
  } else if (dir_exists && !fs::is_empty(dir, ec)) {
    throw InputError(dir.string() + ": is not empty and holds no sweep (jobs.txt); choose another -o");
  }

  const fs::path program = fs::read_symlink("/proc/self/exe");
  std::string jobs_txt;
  for (const auto& j : jobs) jobs_txt += job_line(program, sweep, j, dir, threads) + "\n";
  std::vector<long> pending;
  for (const auto& j : jobs)
    if (!(o.resume && job_status(dir, j.id) == "complete")) pending.push_back(j.id);

  std::string script;
  if (o.slurm) {
    std::ostringstream s;
    s << "#!/bin/bash\n"
      << "# softdiff sweep " << o.file << ": one Slurm array task per job of jobs.txt (task i runs line i+1).\n"
      << "#SBATCH --job-name=" << shell_quote("softdiff-" + fs::path(o.file).stem().string()) << "\n"
      << "#SBATCH --array=" << id_ranges(pending) << (o.jobs ? "%" + std::to_string(*o.jobs) : "") << "\n"
      << "#SBATCH --ntasks=1\n";
    if (slurm_cpus(o.slurm_opts) == 0) s << "#SBATCH --cpus-per-task=1\n";
    s << "#SBATCH --output=" << (dir / "slurm-%A_%a.out").string() << "\n";
    for (const auto& opt : o.slurm_opts) s << "#SBATCH " << opt << "\n";
    s << "line=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" " << shell_quote((dir / "jobs.txt").string()) << ")\n"
      << "exec /bin/sh -c \"$line\"\n";
    script = s.str();
  }
  if (o.dry_run) {
    std::fputs(o.slurm ? script.c_str() : jobs_txt.c_str(), stdout);
    if (!o.quiet)
      note(std::to_string(jobs.size()) + " jobs valid, " + std::to_string(pending.size()) + " to run" +
           (o.slurm ? "" : " (" + std::to_string(at_once) + " at a time, " + std::to_string(threads) + (threads > 1 ? " threads" : " thread") + " each)") +
           "; nothing run (--dry-run)");
    return kExitOk;
  }
  const std::string engine = o.slurm ? "sbatch" : "parallel";
  const std::string engine_path = find_program(engine);
  if (engine_path.empty())
    throw InputError(o.slurm ? "sbatch: not found on PATH (Slurm's client: Debian's slurm-client)"
                             : "parallel: not found on PATH (GNU parallel: Debian's parallel, scripts/setup installs it)");
  if (!o.slurm) {
    std::string version;
    run_program({engine_path, "--version"}, &version);
    if (version.find("GNU parallel") == std::string::npos)
      throw InputError(engine_path + ": is not GNU parallel (moreutils' parallel?): install Debian's parallel");
  }

  // 2. The folder: sweep.yaml (collect re-expands it), jobs.txt.
  fs::create_directories(dir);
  write_file(dir / "sweep.yaml", sweep.text);
  write_file(dir / "jobs.txt", jobs_txt);
  if (pending.empty()) {
    if (!o.quiet) note("all " + std::to_string(jobs.size()) + " jobs are complete in " + dir.string() + " (--resume)");
    return kExitOk;
  }
  for (long id : pending) fs::remove(job_file(dir, id, "exit"), ec);

  if (o.slurm) {
    write_file(dir / "sweep.sbatch", script);
    std::string out;
    const int rc = run_program({engine_path, "--parsable", (dir / "sweep.sbatch").string()}, &out);
    if (rc != 0) {
      error("sbatch " + (dir / "sweep.sbatch").string() + " failed (exit " + std::to_string(rc) + ")");
      return kExitFailed;
    }
    const std::string id = out.substr(0, out.find_first_of(";\n"));
    write_file(dir / "slurm_job_id", id + "\n");
    if (!o.quiet)
      note("submitted Slurm job array " + id + ": " + std::to_string(pending.size()) + " of " + std::to_string(jobs.size()) +
           " jobs (" + dir.string() + "/sweep.sbatch); when it ends: softdiff collect " + dir.string());
    std::printf("%s\n", id.c_str());
    return kExitOk;
  }

  // 3. GNU parallel: the pending lines; a failed job does not stop the others.
  std::string run_txt;
  {
    std::stringstream in(jobs_txt);
    std::string line;
    std::set<long> todo(pending.begin(), pending.end());
    for (long id = 0; std::getline(in, line); ++id)
      if (todo.count(id)) run_txt += line + "\n";
  }
  write_file(dir / "run.txt", run_txt);
  if (!o.quiet)
    note(std::to_string(pending.size()) + " of " + std::to_string(jobs.size()) + " jobs, " + std::to_string(at_once) +
         " at a time, " + std::to_string(threads) + " thread" + (threads > 1 ? "s" : "") + " each -> " + dir.string());
  // The lines are POSIX shell (jobs.txt): whatever the user's login shell ($SHELL, which
  // GNU parallel would use otherwise).
  ::setenv("PARALLEL_SHELL", "/bin/sh", 1);
  Progress progress(static_cast<long>(pending.size()), !o.quiet, "jobs");
  // SIGINT (Ctrl-C), SIGTERM, SIGHUP reach GNU parallel and the jobs (one process
  // group; a handler, unlike an ignored signal, is not inherited through exec): each
  // job stops as docs/cli.md "Signals" says. The sweep itself waits for them and
  // then reports.
  struct sigaction on_signal {}, previous[3];
  on_signal.sa_handler = [](int) {};
  sigemptyset(&on_signal.sa_mask);
  const int watched[3] = {SIGINT, SIGTERM, SIGHUP};
  for (int i = 0; i < 3; ++i) sigaction(watched[i], &on_signal, &previous[i]);
  const auto t0 = std::chrono::steady_clock::now();
  const int rc = run_program({engine_path, "--will-cite", "--jobs", std::to_string(at_once), "--joblog",
                              (dir / "joblog.txt").string(), "-a", (dir / "run.txt").string()},
                             nullptr, [&] {
                               long done = 0;
                               for (long id : pending) done += fs::exists(job_file(dir, id, "exit"), ec);
                               progress.update(done);
                             });
  progress.finish();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  for (int i = 0; i < 3; ++i) sigaction(watched[i], &previous[i], nullptr);
  // parallel's own failure or a signal (> 101), not its count of failed jobs.
  const bool stopped = rc < 0 || rc > 101;
  if (stopped)
    error("parallel stopped (exit " + std::to_string(rc) + ": a signal, or its own failure; its log: " +
          (dir / "joblog.txt").string() + "); softdiff sweep --resume runs the jobs not complete");

  // 4. Summary: failures with their exit codes and messages.
  long complete = 0;
  std::vector<std::string> failures;
  for (long id : pending) {
    const SweepJob& j = jobs[static_cast<std::size_t>(id)];
    std::string exit_text = read_file(job_file(dir, id, "exit"));
    const int code = exit_text.empty() ? -1 : std::atoi(exit_text.c_str());
    const std::string status = job_status(dir, id);
    if (code == 0 && status == "complete") {
      ++complete;
      continue;
    }
    if (code < 0 && status == "missing" && stopped) continue;  // never started

    failures.push_back(job_name(sweep, j) + ": " + status + ", exit " + (code < 0 ? "?" : std::to_string(code)) + ": " +
                       last_line(read_file(job_file(dir, id, "log"))));
  }
  char rate[64];
  std::snprintf(rate, sizeof rate, "%.3g s (%.0f jobs/hour)", seconds, seconds > 0 ? complete * 3600.0 / seconds : 0.0);
  if (!o.quiet || !failures.empty())
    note(std::to_string(complete) + " of " + std::to_string(pending.size()) + " jobs complete in " + rate +
         (failures.empty() ? "" : ", " + std::to_string(failures.size()) + " failed:"));
  for (const auto& f : failures) std::fprintf(stderr, "  %s\n", f.c_str());
  if (!o.quiet && failures.empty()) note("softdiff collect " + dir.string() + " makes the table");
  return failures.empty() && !stopped ? kExitOk : kExitFailed;
}

}  // namespace softdiff::app
