// Sweep files: parsing and expansion (sweep.hpp; the format: docs/cli.md "sweep and collect").
#include "sweep.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_reader.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/input_error.hpp>
#include <softdiff/io/yaml_tree.hpp>

#include <sched.h>

#include <algorithm>
#include <cctype>
#include <cstring>
#include <fstream>
#include <sstream>

namespace softdiff::app {
namespace {

namespace fs = std::filesystem;
using io::yaml::Node;

const std::vector<std::string> kKeys{"softdiff_sweep", "scene", "command", "args", "grid", "zip", "args_grid", "plot"};
const std::vector<std::string> kCommands{"simulate", "calibrate", "control"};

struct Context {
  std::string file;
  [[noreturn]] void fail(const io::yaml::Mark& m, const std::string& path, const std::string& message) const {
    io::Where w;
    w.file = file;
    w.line = m.line;
    w.column = m.column;
    w.path = path;
    io::throw_input_error(w, message);
  }
};

// A value as YAML flow text (for --set KEY=VALUE, parsed as YAML by the scene loader).
std::string flow(const Node& n) {
  switch (n.type) {
    case Node::Type::null: return "null";
    case Node::Type::scalar: {
      if (!n.quoted) return n.scalar;
      std::string s = "\"";
      for (char c : n.scalar) {
        if (c == '"' || c == '\\') s += '\\';
        s += c;
      }
      return s + "\"";
    }
    case Node::Type::sequence: {
      std::string s = "[";
      for (std::size_t i = 0; i < n.items.size(); ++i) s += (i ? ", " : "") + flow(n.items[i]);
      return s + "]";
    }
    case Node::Type::map: {
      std::string s = "{";
      for (std::size_t i = 0; i < n.entries.size(); ++i)
        s += (i ? ", " : "") + n.entries[i].key + ": " + flow(n.entries[i].value);
      return s + "}";
    }
  }
  return "";
}

std::string scalar_text(const Context& c, const Node& n, const std::string& path) {
  if (!n.is_scalar()) c.fail(n.mark, path, "must be a string, got " + io::yaml::describe(n));
  return n.scalar;
}

void read_axes(const Context& c, const io::yaml::Entry& section, SweepAxis::Kind kind, std::vector<SweepAxis>& out) {
  const Node& map = section.value;
  if (map.is_null()) return;
  if (!map.is_map())
    c.fail(map.mark.line ? map.mark : section.key_mark, section.key,
           "must be a map of " + std::string(kind == SweepAxis::Kind::args ? "options" : "scene paths") +
               " to lists of values, got " + io::yaml::describe(map));
  std::size_t zip_length = 0;
  for (const auto& e : map.entries) {
    const std::string path = section.key + "." + e.key;
    if (kind == SweepAxis::Kind::args && (e.key.size() < 2 || e.key[0] != '-'))
      c.fail(e.key_mark, path, "must be a command-line option (starting with -), e.g. --target");
    if (kind != SweepAxis::Kind::args && (e.key.empty() || e.key[0] == '-'))
      c.fail(e.key_mark, path, "must be a scene path as for --set (e.g. bodies.beam.material.young)");
    if (!e.value.is_sequence() || e.value.items.empty())
      c.fail(e.key_mark, path, "must be a non-empty list of values, got " + io::yaml::describe(e.value));
    if (kind == SweepAxis::Kind::zip) {
      if (zip_length == 0) zip_length = e.value.items.size();
      if (e.value.items.size() != zip_length)
        c.fail(e.key_mark, path,
               "zip axes must have equal lengths: " + std::to_string(e.value.items.size()) + " values, the first axis has " +
                   std::to_string(zip_length));
    }
    for (const auto& a : out)
      if (a.name == e.key) c.fail(e.key_mark, path, "is already an axis (" + std::to_string(a.line) + ":" +
                                                        std::to_string(a.column) + ")");
    SweepAxis axis;
    axis.kind = kind;
    axis.name = e.key;
    axis.line = e.key_mark.line;
    axis.column = e.key_mark.column;
    for (std::size_t i = 0; i < e.value.items.size(); ++i) {
      const Node& v = e.value.items[i];
      if (kind == SweepAxis::Kind::args) {
        axis.values.push_back(scalar_text(c, v, io::yaml::index_path(path, i)));
        axis.labels.push_back(axis.values.back());
      } else {
        axis.values.push_back(flow(v));
        axis.labels.push_back(v.is_scalar() ? v.scalar : flow(v));
      }
    }
    out.push_back(std::move(axis));
  }
}

}  // namespace

SweepDesc parse_sweep(const std::string& text, const fs::path& file, bool need_scene) {
  Context c{file.string()};
  Node root;
  try {
    root = io::yaml::parse(text, false);
  } catch (const io::yaml::ParseError& e) {
    c.fail(e.mark, e.path, e.message);
  }
  if (!root.is_map()) c.fail(root.mark, "", "a sweep file is a map (softdiff_sweep: 1, scene, command, grid, ...)");
  for (const auto& e : root.entries)
    if (std::find(kKeys.begin(), kKeys.end(), e.key) == kKeys.end()) {
      const auto near = io::closest_match(e.key, kKeys);
      c.fail(e.key_mark, e.key,
             "unknown key" + (near ? "; did you mean '" + *near + "'?" : "; expected one of " + io::join(kKeys)));
    }
  SweepDesc s;
  s.file = file;
  s.text = text;
  const io::yaml::Entry* version = root.find("softdiff_sweep");
  if (!version) c.fail(root.mark, "softdiff_sweep", "missing: a sweep file starts with 'softdiff_sweep: 1'");
  if (io::yaml::to_integer(version->value) != 1)
    c.fail(version->value.mark, "softdiff_sweep", "must be 1, got " + io::yaml::describe(version->value));

  const io::yaml::Entry* scene = root.find("scene");
  if (!scene) c.fail(root.mark, "scene", "missing: the base scene file (relative to the sweep file)");
  const fs::path scene_path = scalar_text(c, scene->value, "scene");
  s.scene = scene_path.is_absolute() ? scene_path : fs::absolute(file).parent_path() / scene_path;
  s.scene = s.scene.lexically_normal();
  std::error_code ec;
  if (need_scene && !fs::is_regular_file(s.scene, ec))
    c.fail(scene->value.mark, "scene", "no such file: " + s.scene.string());

  const io::yaml::Entry* command = root.find("command");
  if (!command) c.fail(root.mark, "command", "missing: one of " + io::join(kCommands));
  s.command = scalar_text(c, command->value, "command");
  if (std::find(kCommands.begin(), kCommands.end(), s.command) == kCommands.end()) {
    const auto near = io::closest_match(s.command, kCommands);
    c.fail(command->value.mark, "command",
           "must be one of " + io::join(kCommands) + ", got '" + s.command + "'" +
               (near ? "; did you mean '" + *near + "'?" : ""));
  }
  if (const io::yaml::Entry* args = root.find("args")) {
    if (!args->value.is_null() && !args->value.is_sequence())
      c.fail(args->value.mark, "args", "must be a list of command-line arguments, got " + io::yaml::describe(args->value));
    for (std::size_t i = 0; i < args->value.items.size(); ++i)
      s.args.push_back(scalar_text(c, args->value.items[i], io::yaml::index_path("args", i)));
  }
  // Axes: grid, zip, args_grid (the order of the loops, whatever the order of the keys).
  for (const auto& [key, kind] : {std::pair{"grid", SweepAxis::Kind::grid}, std::pair{"zip", SweepAxis::Kind::zip},
                                  std::pair{"args_grid", SweepAxis::Kind::args}})
    if (const io::yaml::Entry* e = root.find(key)) read_axes(c, *e, kind, s.axes);
  // Options the sweep sets itself.
  for (std::size_t i = 0; i < s.args.size(); ++i)
    for (const char* own : {"-o", "--output", "--json", "--quiet", "--force"})
      if (s.args[i] == own || s.args[i].rfind(std::string(own) + "=", 0) == 0)
        c.fail(root.find("args")->value.items[i].mark, io::yaml::index_path("args", i),
               std::string(own) + " is set by the sweep for every job (output DIR/<job>.h5, JSON in DIR/<job>.json)");
  for (const auto& a : s.axes)
    for (const char* own : {"-o", "--output", "--json", "--quiet", "--force"})
      if (a.kind == SweepAxis::Kind::args && a.name == own)
        c.fail({a.line, a.column, false}, "args_grid." + a.name, std::string(own) + " is set by the sweep for every job");

  if (const io::yaml::Entry* plot = root.find("plot")) {
    const Node& p = plot->value;
    if (!p.is_map()) c.fail(p.mark, "plot", "must be a map {x: AXIS, y: AXIS, value: COLUMN}");
    SweepPlot sp;
    for (const auto& e : p.entries) {
      const std::string path = "plot." + e.key;
      std::string* field = e.key == "x" ? &sp.x : e.key == "y" ? &sp.y : e.key == "value" ? &sp.value : nullptr;
      if (!field) {
        const auto near = io::closest_match(e.key, {"x", "y", "value"});
        c.fail(e.key_mark, path, "unknown key" + (near ? "; did you mean '" + *near + "'?" : "; expected x, y, value"));
      }
      *field = scalar_text(c, e.value, path);
      if (e.key != "value") {
        bool known = false;
        std::vector<std::string> names;
        for (const auto& a : s.axes) {
          known = known || a.name == *field;
          names.push_back(a.name);
        }
        if (!known) c.fail(e.value.mark, path, "'" + *field + "' is not an axis; axes: " + io::join(names));
      }
    }
    for (const auto& [key, field] : {std::pair{"x", &sp.x}, std::pair{"y", &sp.y}, std::pair{"value", &sp.value}})
      if (field->empty()) c.fail(p.mark, std::string("plot.") + key, "missing");
    s.plot = sp;
  }
  return s;
}

SweepDesc load_sweep(const fs::path& file, bool need_scene) {
  std::ifstream in(file);
  if (!in) throw InputError(file.string() + ": cannot read sweep file: " + std::strerror(errno));
  std::stringstream text;
  text << in.rdbuf();
  return parse_sweep(text.str(), file, need_scene);
}

std::vector<SweepJob> expand_sweep(const SweepDesc& sweep) {
  // Loops: each grid and args_grid axis is one; the zip axes together are one.
  struct Loop {
    std::vector<std::size_t> axes;
    std::size_t size = 0;
  };
  std::vector<Loop> loops;
  for (std::size_t a = 0; a < sweep.axes.size(); ++a) {
    const SweepAxis& axis = sweep.axes[a];
    if (axis.kind == SweepAxis::Kind::zip && !loops.empty() &&
        sweep.axes[loops.back().axes.front()].kind == SweepAxis::Kind::zip) {
      loops.back().axes.push_back(a);
      continue;
    }
    loops.push_back({{a}, axis.values.size()});
  }
  std::size_t total = 1;
  for (const auto& l : loops) total *= l.size;
  std::vector<SweepJob> jobs;
  jobs.reserve(total);
  for (std::size_t id = 0; id < total; ++id) {
    SweepJob job;
    job.id = static_cast<long>(id);
    job.index.assign(sweep.axes.size(), 0);
    std::size_t rest = id;
    for (std::size_t l = loops.size(); l-- > 0;) {  // the last loop varies fastest
      const std::size_t i = rest % loops[l].size;
      rest /= loops[l].size;
      for (std::size_t a : loops[l].axes) job.index[a] = i;
    }
    job.args = sweep.args;
    for (std::size_t a = 0; a < sweep.axes.size(); ++a) {
      const SweepAxis& axis = sweep.axes[a];
      const std::string& v = axis.values[job.index[a]];
      if (axis.kind == SweepAxis::Kind::args && axis.name.rfind("--", 0) == 0) {
        job.args.push_back(axis.name + "=" + v);  // one word: a value may start with '-' (--target=-0.03,0,0.1)
      } else if (axis.kind == SweepAxis::Kind::args) {
        job.args.push_back(axis.name);
        job.args.push_back(v);
      } else {
        job.sets.push_back(axis.name + "=" + v);
      }
    }
    jobs.push_back(std::move(job));
  }
  return jobs;
}

bool has_option(const std::vector<std::string>& args, const std::string& name) {
  for (const auto& a : args)
    if (a == name || a.rfind(name + "=", 0) == 0) return true;
  return false;
}

fs::path job_file(const fs::path& dir, long id, const std::string& ext) { return dir / (std::to_string(id) + "." + ext); }

std::vector<std::string> job_arguments(const SweepDesc& sweep, const SweepJob& job, const fs::path& dir, int threads) {
  std::vector<std::string> a{sweep.command, sweep.scene.string()};
  for (const auto& s : job.sets) {
    a.push_back("--set");
    a.push_back(s);
  }
  a.insert(a.end(), job.args.begin(), job.args.end());
  if (threads > 0 && !has_option(job.args, "--threads")) {
    a.push_back("--threads");
    a.push_back(std::to_string(threads));
  }
  for (const char* flag : {"--quiet", "--json", "--force"}) a.push_back(flag);
  a.push_back("-o");
  a.push_back(job_file(dir, job.id, "h5").string());
  return a;
}

std::string shell_quote(const std::string& s) {
  bool plain = !s.empty();
  for (char c : s)
    plain = plain && (std::isalnum(static_cast<unsigned char>(c)) || std::string_view("-_./=,:+@%").find(c) != std::string_view::npos);
  if (plain) return s;
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string job_line(const fs::path& program, const SweepDesc& sweep, const SweepJob& job, const fs::path& dir,
                     int threads) {
  std::string line = "cd " + shell_quote(fs::absolute(sweep.file).parent_path().string()) + " && t0=$(date +%s.%N) && ";
  // OpenBLAS (CHOLMOD's BLAS) starts a thread per core unless told: the job's share.
  if (threads > 0 && !has_option(job.args, "--threads")) line += "OPENBLAS_NUM_THREADS=" + std::to_string(threads) + " ";
  line += shell_quote(program.string());
  for (const auto& a : job_arguments(sweep, job, dir, threads)) line += " " + shell_quote(a);
  line += " >" + shell_quote(job_file(dir, job.id, "json").string()) + " 2>" +
          shell_quote(job_file(dir, job.id, "log").string());
  line += "; rc=$?; echo \"$rc $t0 $(date +%s.%N)\" >" + shell_quote(job_file(dir, job.id, "exit").string()) +
          "; exit $rc";
  return line;
}

std::string job_status(const fs::path& dir, long id, fs::path* found) {
  const fs::path output = dir / (std::to_string(id) + ".h5");
  // The output, else the side files of an unfinished run over an existing output
  // (docs/output.md), else a .partial left by a killed run.
  for (const fs::path& file : {output, io::side_file_name(output, "interrupted"),
                               io::side_file_name(output, "diverged"), io::side_file_name(output, "failed"),
                               fs::path(output.string() + ".partial")}) {
    // "": no file, not HDF5, or no status attribute (a file that exists is then "failed").
    const std::string status = io::read_status(file).value_or("");
    std::error_code ec;
    if (status.empty() && !fs::exists(file, ec)) continue;
    if (found) *found = file;
    for (const char* s : {"complete", "interrupted", "diverged", "failed"})
      if (status.rfind(s, 0) == 0) return s;
    return "failed";  // running (a killed run), or not a readable softdiff output
  }
  return "missing";
}

int available_cores() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof set, &set) == 0) return std::max(1, CPU_COUNT(&set));
  return 1;
}

}  // namespace softdiff::app
