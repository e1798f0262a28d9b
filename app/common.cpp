#include "common.hpp"
#include "commands.hpp"

#include <softdiff/core/error.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/io/scene.hpp>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <filesystem>
#include <iomanip>
#include <thread>
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

namespace {

volatile std::sig_atomic_t g_signal_count = 0;
int g_signal_pipe[2] = {-1, -1};
constexpr int kWatchedSignals[] = {SIGINT, SIGTERM, SIGHUP};

extern "C" void on_watched_signal(int signal) {
  const int saved = errno;
  g_signal_count = g_signal_count + 1;
  const char byte = static_cast<char>(signal);
  if (g_signal_pipe[1] >= 0) {
    [[maybe_unused]] const auto n = ::write(g_signal_pipe[1], &byte, 1);
  }
  errno = saved;
}

const char* signal_name(int signal) {
  switch (signal) {
    case SIGINT: return "SIGINT";
    case SIGTERM: return "SIGTERM";
    case SIGHUP: return "SIGHUP";
    default: return "signal";
  }
}

}  // namespace

struct SignalWatch::Impl {
  std::function<void(int, const char*)> on_signal;
  struct sigaction previous[3] {};
  std::thread watcher;
};

SignalWatch::SignalWatch(std::function<void(int count, const char* name)> on_signal) : impl_(new Impl) {
  impl_->on_signal = std::move(on_signal);
  g_signal_count = 0;
  if (::pipe(g_signal_pipe) != 0) g_signal_pipe[0] = g_signal_pipe[1] = -1;
  struct sigaction action {};
  action.sa_handler = on_watched_signal;
  sigemptyset(&action.sa_mask);
  action.sa_flags = SA_RESTART;  // HDF5's and stdio's system calls are not cut short
  for (int i = 0; i < 3; ++i) sigaction(kWatchedSignals[i], &action, &impl_->previous[i]);
  if (g_signal_pipe[0] >= 0) {
    impl_->watcher = std::thread([impl = impl_] {
      int count = 0;
      for (;;) {
        char byte = 0;
        const auto n = ::read(g_signal_pipe[0], &byte, 1);
        if (n < 0 && errno == EINTR) continue;
        if (n != 1 || byte == 0) return;  // 0: the watch ends
        impl->on_signal(++count, signal_name(byte));
      }
    });
  }
}

SignalWatch::~SignalWatch() {
  for (int i = 0; i < 3; ++i) sigaction(kWatchedSignals[i], &impl_->previous[i], nullptr);
  if (impl_->watcher.joinable()) {
    const char stop = 0;
    [[maybe_unused]] const auto n = ::write(g_signal_pipe[1], &stop, 1);
    impl_->watcher.join();
  }
  for (int& fd : g_signal_pipe) {
    if (fd >= 0) ::close(fd);
    fd = -1;
  }
  delete impl_;
}

bool SignalWatch::stop_requested() { return g_signal_count > 0; }

void add_run_options(CLI::App& app, std::string& output, const std::string& output_help, bool& force,
                     std::vector<std::string>& set, int& threads, bool& strict, bool& quiet,
                     const std::string& quiet_help, bool& json) {
  app.add_option("-o,--output", output, output_help);
  app.add_flag("--force", force, "Overwrite an existing output file");
  app.add_option("--set", set, "Override a scene value: KEY=VALUE (repeatable)");
  app.add_option("--threads", threads, "OpenMP threads (default: all cores)")->check(CLI::NonNegativeNumber);
  app.add_flag("--strict", strict, "Treat a contact solve that does not reach its tolerance as an error (exit 1), and a body of implausible size or mass as bad input (exit 2)");
  app.add_flag("--quiet", quiet, quiet_help);
  app.add_flag("--json", json, "Print a JSON summary on stdout");
}

CLI::Validator positive_number(const std::string& unit) {
  return CLI::Validator(
      [unit](std::string& text) -> std::string {
        errno = 0;
        char* end = nullptr;
        const double value = std::strtod(text.c_str(), &end);
        if (text.empty() || end == text.c_str() || *end != '\0' || errno == ERANGE)
          return "must be a number" + (unit.empty() ? std::string() : " of " + unit) + ", got '" + text + "'";
        if (!(value > 0) || !std::isfinite(value))
          return "must be > 0" + (unit.empty() ? std::string() : " " + unit) + ", got " + text;
        return {};
      },
      "> 0");
}

CLI::Validator positive_integer() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        errno = 0;
        char* end = nullptr;
        const long long value = std::strtoll(text.c_str(), &end, 10);
        if (text.empty() || end == text.c_str() || *end != '\0' || errno == ERANGE)
          return "must be a whole number >= 1, got '" + text + "'";
        if (value < 1) return "must be >= 1, got " + text;
        return {};
      },
      ">= 1");
}

}  // namespace softdiff::app
