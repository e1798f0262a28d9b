// softdiff collect DIR: one row per job of a sweep (CSV, and HDF5 with the same
// columns), and a PNG of one result over two axes (docs/cli.md "sweep and collect").
#include "commands.hpp"
#include "common.hpp"
#include "sweep.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_reader.hpp>
#include <softdiff/io/hdf5_table.hpp>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>

extern char** environ;

namespace softdiff::app {
namespace {

namespace fs = std::filesystem;

// A table: columns in the order they first appear; cells as text ("" for none).
struct Table {
  std::vector<std::string> columns;
  std::map<std::string, std::string> units;
  std::vector<std::map<std::string, std::string>> rows;
  void set(std::size_t row, const std::string& column, const std::string& value, const std::string& unit) {
    if (std::find(columns.begin(), columns.end(), column) == columns.end()) {
      columns.push_back(column);
      units[column] = unit;
    }
    rows[row][column] = value;
  }
};

std::string number(double v) {
  if (!std::isfinite(v)) return "";
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// The command's scalar results of a complete output (docs/cli.md "sweep and collect", collect).
void read_results(const io::Hdf5Reader& out, const std::string& command, Table& t, std::size_t row) {
  const std::vector<double> step_seconds = out.read("/solver/step_seconds");
  if (step_seconds.size() > 1) {
    double sum = 0;
    for (std::size_t k = 1; k < step_seconds.size(); ++k) sum += step_seconds[k];
    t.set(row, "ms_per_step", number(1e3 * sum / static_cast<double>(step_seconds.size() - 1)), "ms");
  }
  // The final frame: the largest displacement over every body, the effectors.
  const std::vector<std::string> bodies = out.members("/bodies");
  double max_displacement = -1;
  for (const auto& b : bodies) {
    std::vector<std::size_t> shape;
    const std::vector<double> d = out.read("/bodies/" + b + "/displacement", &shape);
    if (shape.size() == 3 && shape[0] > 0) {
      const std::size_t n = shape[1], last = (shape[0] - 1) * n * 3;
      for (std::size_t i = 0; i < n; ++i)
        max_displacement = std::max(max_displacement, std::hypot(d[last + 3 * i], d[last + 3 * i + 1], d[last + 3 * i + 2]));
    }
  }
  if (max_displacement >= 0) t.set(row, "max_displacement", number(max_displacement), "m");
  for (const auto& b : bodies)
    for (const auto& e : out.members("/bodies/" + b + "/effectors")) {
      std::vector<std::size_t> shape;
      const std::vector<double> p = out.read("/bodies/" + b + "/effectors/" + e, &shape);
      if (shape.size() != 2 || shape[0] == 0 || shape[1] != 3) continue;
      const std::string name = (bodies.size() > 1 ? b + "." : "") + e;
      for (int c = 0; c < 3; ++c) t.set(row, name + "." + "xyz"[c], number(p[(shape[0] - 1) * 3 + c]), "m");
    }
  if (command == "calibrate") {
    // /calibration's attributes: each parameter's value, then converged, iterations, final_cost.
    std::vector<std::pair<std::string, double>> attributes = out.numeric_attributes("/calibration");
    for (const auto& [name, v] : attributes)
      if (name != "converged" && name != "iterations" && name != "final_cost" && name != "evaluations")
        t.set(row, name, number(v), "SI (the parameter's unit, docs/output.md /calibration)");
    for (const auto& [name, v] : attributes)
      if (name == "final_cost") t.set(row, "final_cost", number(v), "m^2");
    for (const auto& [name, v] : attributes)
      if (name == "iterations" || name == "converged") t.set(row, name, number(v), "1");
  }
  if (command == "control") {
    const std::vector<double> distance = out.read("/control/distance");
    if (!distance.empty()) t.set(row, "final_distance", number(distance.back()), "m");
    const std::vector<double> force = out.read("/control/contact_force_norm");
    if (force.size() > 1) {
      double sum = 0;
      for (std::size_t k = 1; k < force.size(); ++k) sum += force[k];  // frame 0 has no contact step
      t.set(row, "mean_contact_force", number(sum / static_cast<double>(force.size() - 1)), "N");
    }
  }
}

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string q = "\"";
  for (char c : s) q += c == '"' ? std::string("\"\"") : std::string(1, c);
  return q + "\"";
}

bool is_number(const std::string& s, double* v) {
  if (s.empty()) return false;
  char* end = nullptr;
  const double x = std::strtod(s.c_str(), &end);
  if (*end != '\0') return false;
  if (v) *v = x;
  return true;
}

// The table as HDF5 (io::write_hdf5_table): a float64 column where every cell is a
// number or empty (NaN for empty), else strings, in the CSV's order, each with its units.
void write_table_h5(const fs::path& path, const Table& t) {
  std::vector<io::TableColumn> columns;
  for (const auto& c : t.columns) {
    bool numeric = true;
    std::vector<double> values;
    std::vector<std::string> texts;
    for (const auto& r : t.rows) {
      const auto it = r.find(c);
      const std::string s = it == r.end() ? "" : it->second;
      double v = std::numeric_limits<double>::quiet_NaN();
      if (!s.empty() && !is_number(s, &v)) numeric = false;
      values.push_back(v);
      texts.push_back(s);
    }
    io::TableColumn column{c, t.units.at(c), {}};
    if (numeric)
      column.values = std::move(values);
    else
      column.values = std::move(texts);
    columns.push_back(std::move(column));
  }
  io::write_hdf5_table(path, columns);
}

// The PNG: matplotlib (Debian's python3-matplotlib) draws the table's value over the
// two axes; cells that several jobs share (other axes) show their mean.
const char* kPlotScript = R"PY(
import csv, os, sys
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
table, png, x, y, value = sys.argv[1:6]
rows = list(csv.DictReader(open(table, newline="")))
xs, ys, cells = [], [], {}
for r in rows:
    if r[x] not in xs: xs.append(r[x])
    if r[y] not in ys: ys.append(r[y])
    if r.get(value, "") != "": cells.setdefault((r[x], r[y]), []).append(float(r[value]))
grid = [[float("nan")] * len(xs) for _ in ys]
for (a, b), v in cells.items(): grid[ys.index(b)][xs.index(a)] = sum(v) / len(v)
fig, ax = plt.subplots(figsize=(max(5.0, 2.0 + 1.2 * len(xs)), max(3.2, 1.8 + 0.5 * len(ys))), constrained_layout=True)
im = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis")
finite = [v for row in grid for v in row if v == v]
lo, hi = (min(finite), max(finite)) if finite else (0.0, 1.0)
for j, row in enumerate(grid):
    for i, v in enumerate(row):
        light = hi > lo and (v - lo) / (hi - lo) > 0.6  # viridis is light at the top
        if v == v: ax.text(i, j, "%.4g" % v, ha="center", va="center", color="k" if light else "w", fontsize=8)
# File names (targets, marker CSVs) by their stem.
short = lambda v: os.path.splitext(os.path.basename(v))[0] if "/" in v or v.endswith((".h5", ".csv")) else v
ax.set_xticks(range(len(xs)), [short(v) for v in xs], rotation=30 if max(len(short(v)) for v in xs) > 6 else 0, ha="right" if max(len(short(v)) for v in xs) > 6 else "center")
ax.set_yticks(range(len(ys)), [short(v) for v in ys])
ax.set_xlabel(x); ax.set_ylabel(y)
fig.colorbar(im, ax=ax, label=value)
ax.set_title("softdiff collect: %s (%d jobs)" % (value, len(rows)), fontsize=9)
fig.savefig(png, dpi=110)
)PY";

int run_python(const std::vector<std::string>& args, std::string& err_text, const fs::path& err_file) {
  std::vector<std::string> words = args;
  std::vector<char*> argv;
  for (auto& w : words) argv.push_back(w.data());
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, err_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, "/dev/null", O_WRONLY, 0);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) return -1;
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  std::ifstream in(err_file);
  std::stringstream s;
  s << in.rdbuf();
  err_text = s.str();
  fs::remove(err_file);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

void add_collect(CLI::App& app, CollectOptions& o) {
  app.add_option("dir", o.dir, "A sweep's output folder (softdiff sweep -o DIR)")->required();
  app.add_option("-o,--output", o.table,
                 "Table (CSV; the HDF5 table and the PNG get the same stem: TABLE.h5, TABLE.png). Default DIR/results.csv");
  app.add_flag("--quiet", o.quiet, "No summary line");
}

int run_collect(const CollectOptions& o) {
  const fs::path dir = fs::absolute(o.dir).lexically_normal();
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw InputError(o.dir + ": not a folder (a sweep's output: softdiff sweep -o DIR)");
  if (!fs::is_regular_file(dir / "sweep.yaml", ec) || !fs::is_regular_file(dir / "jobs.txt", ec))
    throw InputError(o.dir + ": holds no sweep (sweep.yaml and jobs.txt, written by softdiff sweep)");
  std::ifstream in(dir / "sweep.yaml");
  std::stringstream text;
  text << in.rdbuf();
  const SweepDesc sweep = parse_sweep(text.str(), dir / "sweep.yaml", false);
  const std::vector<SweepJob> jobs = expand_sweep(sweep);
  const fs::path csv = o.table.empty() ? dir / "results.csv" : fs::absolute(o.table);
  if (csv.extension() != ".csv") throw InputError(o.table + ": the table must be a .csv file (TABLE.h5 and TABLE.png go beside it)");
  fs::path h5 = csv, png = csv;
  h5.replace_extension(".h5");
  png.replace_extension(".png");

  Table t;
  t.rows.resize(jobs.size());
  long complete = 0;
  for (std::size_t r = 0; r < jobs.size(); ++r) {
    const SweepJob& j = jobs[r];
    t.set(r, "job", std::to_string(j.id), "1");
    for (std::size_t a = 0; a < sweep.axes.size(); ++a)
      t.set(r, sweep.axes[a].name, sweep.axes[a].labels[j.index[a]],
            sweep.axes[a].kind == SweepAxis::Kind::args ? "1" : "SI (the scene path's unit, docs/scene.md)");
    fs::path found;
    const std::string status = job_status(dir, j.id, &found);
    t.set(r, "status", status, "1");
    std::ifstream ex(job_file(dir, j.id, "exit"));
    int code = -1;
    double start = 0, end = 0;
    if (ex >> code >> start >> end) {
      t.set(r, "exit_code", std::to_string(code), "1");
      t.set(r, "wall_s", number(end - start), "s");
    } else {
      t.set(r, "exit_code", "", "1");
      t.set(r, "wall_s", "", "s");
    }
    if (status == "complete") {
      const io::Hdf5Reader out(found);
      if (out.ok()) read_results(out, sweep.command, t, r);
    }
    complete += status == "complete" && code == 0;
  }

  {
    const fs::path partial = csv.string() + ".partial";
    std::ofstream f(partial);
    for (std::size_t c = 0; c < t.columns.size(); ++c) f << (c ? "," : "") << csv_field(t.columns[c]);
    f << "\n";
    for (const auto& row : t.rows) {
      for (std::size_t c = 0; c < t.columns.size(); ++c) {
        const auto it = row.find(t.columns[c]);
        f << (c ? "," : "") << csv_field(it == row.end() ? "" : it->second);
      }
      f << "\n";
    }
    f.close();
    if (!f) throw ComputationError(csv.string() + ": cannot write the table");
    fs::rename(partial, csv);
  }
  write_table_h5(h5, t);

  bool plotted = false;
  if (sweep.plot) {
    const auto& p = *sweep.plot;
    if (std::find(t.columns.begin(), t.columns.end(), p.value) == t.columns.end()) {
      warn("plot.value: no column '" + p.value + "' in the table (columns: " + [&] {
        std::string s;
        for (const auto& c : t.columns) s += (s.empty() ? "" : ", ") + c;
        return s;
      }() + "); no PNG");
    } else if (::access("/usr/bin/python3", X_OK) != 0) {
      warn("no PNG: /usr/bin/python3 (with Debian's python3-matplotlib) is not installed");
    } else {
      std::string err;
      const int rc = run_python({"/usr/bin/python3", "-c", kPlotScript, csv.string(), png.string(), p.x, p.y, p.value}, err,
                                png.string() + ".stderr");
      if (rc != 0)
        warn("no PNG: matplotlib failed (Debian's python3-matplotlib; scripts/setup installs it): " + err);
      else
        plotted = true;
    }
  }
  if (!o.quiet)
    note(std::to_string(complete) + " of " + std::to_string(jobs.size()) + " jobs complete -> " + csv.string() + ", " +
         h5.string() + (plotted ? ", " + png.string() : ""));
  return complete == static_cast<long>(jobs.size()) ? kExitOk : kExitFailed;
}

}  // namespace softdiff::app
