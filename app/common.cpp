#include "common.hpp"
#include "commands.hpp"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <unistd.h>

namespace softdiff::app {

void warn(const std::string& message) { std::fprintf(stderr, "softdiff: warning: %s\n", message.c_str()); }
void error(const std::string& message) { std::fprintf(stderr, "softdiff: error: %s\n", message.c_str()); }
void note(const std::string& message) { std::fprintf(stderr, "softdiff: %s\n", message.c_str()); }

std::string json_escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
      case '\r': out += "\\r"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04x", c);
          out += buf;
        } else {
          out += c;
        }
    }
  }
  return out;
}

void Json::key(const std::string& k) {
  if (!first_.back()) out_ << ",";
  first_.back() = false;
  if (!k.empty()) out_ << "\"" << json_escape(k) << "\":";
}
Json& Json::begin_object(const std::string& k) {
  key(k);
  out_ << "{";
  first_.push_back(true);
  return *this;
}
Json& Json::end_object() {
  out_ << "}";
  first_.pop_back();
  return *this;
}
Json& Json::begin_array(const std::string& k) {
  key(k);
  out_ << "[";
  first_.push_back(true);
  return *this;
}
Json& Json::end_array() {
  out_ << "]";
  first_.pop_back();
  return *this;
}
Json& Json::value(const std::string& k, double v) {
  key(k);
  if (std::isfinite(v))
    out_ << std::setprecision(17) << v;
  else
    out_ << "null";
  return *this;
}
Json& Json::value(const std::string& k, long v) {
  key(k);
  out_ << v;
  return *this;
}
Json& Json::value(const std::string& k, bool v) {
  key(k);
  out_ << (v ? "true" : "false");
  return *this;
}
Json& Json::value(const std::string& k, const std::string& v) {
  key(k);
  out_ << "\"" << json_escape(v) << "\"";
  return *this;
}
Json& Json::value(const std::string& k, const std::vector<double>& v) {
  begin_array(k);
  for (double x : v) value("", x);
  return end_array();
}

Progress::Progress(long total, bool enabled, std::string unit)
    : total_(total), enabled_(enabled && isatty(STDERR_FILENO)), unit_(std::move(unit)),
      start_(std::chrono::steady_clock::now()), last_(start_) {}

void Progress::start(long total, std::string label) {
  total_ = total;
  done_ = 0;
  label_ = std::move(label);
  start_ = last_ = std::chrono::steady_clock::now();
}

void Progress::update(long done) {
  done_ = done;
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  if (done < total_ && drawn_ > 0 && std::chrono::duration<double>(now - last_).count() < 0.1) return;
  last_ = now;
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  const double rate = elapsed > 0 ? done / elapsed : 0;
  const double eta = rate > 0 ? (total_ - done) / rate : 0;
  constexpr int width = 30;
  const int filled = total_ > 0 ? static_cast<int>(width * std::min(done, total_) / total_) : width;
  std::string bar(static_cast<std::size_t>(filled), '=');
  bar.resize(width, ' ');
  char line[256];
  const int n = std::snprintf(line, sizeof line, "%s%s[%s] %ld/%ld %s  %.1f %s/s  ETA %.0f s", label_.c_str(),
                              label_.empty() ? "" : " ", bar.c_str(), done, total_, unit_.c_str(), rate, unit_.c_str(), eta);
  const int len = std::min<int>(n, static_cast<int>(sizeof line) - 1);
  // Pad over a longer previous line.
  std::fprintf(stderr, "\r%s%*s", line, std::max(0, drawn_ - len), "");
  drawn_ = std::max(drawn_, len);
  std::fflush(stderr);
}

void Progress::clear() {
  if (!enabled_ || drawn_ == 0) return;
  std::fprintf(stderr, "\r%*s\r", drawn_, "");
  std::fflush(stderr);
  drawn_ = 0;
}

void note(Progress& progress, const std::string& message) {
  progress.clear();
  note(message);
}

std::string join_argv(int argc, char** argv) {
  std::string s;
  for (int i = 0; i < argc; ++i) {
    if (i) s += ' ';
    s += argv[i];
  }
  return s;
}

std::vector<std::string> split_list(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, sep)) {
    item.erase(0, item.find_first_not_of(" \t\r"));
    item.erase(item.find_last_not_of(" \t\r") + 1);
    out.push_back(item);
  }
  if (!s.empty() && s.back() == sep) out.push_back("");
  return out;
}

void add_run_options(CLI::App& app, std::string& output, const std::string& output_help, bool& force,
                     std::vector<std::string>& set, int& threads, bool& strict, bool& quiet,
                     const std::string& quiet_help, bool& json) {
  app.add_option("-o,--output", output, output_help);
  app.add_flag("--force", force, "Overwrite an existing output file");
  app.add_option("--set", set, "Override a scene value: KEY=VALUE (repeatable)");
  app.add_option("--threads", threads, "OpenMP threads (default: all cores)")->check(CLI::NonNegativeNumber);
  app.add_flag("--strict", strict, "Treat a contact solve that does not reach its tolerance as an error (exit 1)");
  app.add_flag("--quiet", quiet, quiet_help);
  app.add_flag("--json", json, "Print a JSON summary on stdout");
}

}  // namespace softdiff::app
