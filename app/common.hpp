#pragma once
// Shared helpers of the subcommands: messages, JSON output, progress bar, timers.
#include <chrono>
#include <cstdio>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <softdiff/core/text.hpp>

namespace softdiff::app {

// Exit codes (cli.md): 0 success, 1 computation failed, 2 bad usage or input.
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailed = 1;
inline constexpr int kExitBadInput = 2;

void warn(const std::string& message);
void error(const std::string& message);
void note(const std::string& message);  // informational, suppressed by --quiet

// A minimal JSON writer (objects, arrays, numbers, strings, booleans).
class Json {
 public:
  Json& begin_object(const std::string& key = "");
  Json& end_object();
  Json& begin_array(const std::string& key = "");
  Json& end_array();
  Json& value(const std::string& key, double v);
  Json& value(const std::string& key, long v);
  Json& value(const std::string& key, int v) { return value(key, static_cast<long>(v)); }
  Json& value(const std::string& key, bool v);
  Json& value(const std::string& key, const std::string& v);
  Json& value(const std::string& key, const char* v) { return value(key, std::string(v)); }
  Json& value(const std::string& key, const std::vector<double>& v);
  std::string str() const { return out_.str(); }

 private:
  void key(const std::string& k);
  std::ostringstream out_;
  std::vector<bool> first_{true};
};
std::string json_escape(const std::string& s);

// Progress bar on stderr when it is a terminal (not on a pipe, not with --quiet):
//   [=====     ] 40/100 steps  12.3 steps/s  ETA 5 s
// one line redrawn in place (at most 10 times a second, and at the end). `unit` names
// what is counted ("steps", "runs"); a label set with start() prefixes the bar (e.g.
// "run 3"). simulate, control, check-grad and calibrate draw their progress with it.
class Progress {
 public:
  Progress(long total, bool enabled, std::string unit = "steps");
  ~Progress() { clear(); }  // an error message after an exception starts on a clean line
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;
  // A new count from 0 (rate and ETA restart), with an optional label before the bar.
  void start(long total, std::string label = "");
  void update(long done);
  void advance(long n = 1) { update(done_ + n); }
  void set_total(long total) { total_ = total; }
  long total() const { return total_; }
  // Erases the bar (before a message line, and at the end); the next update redraws it.
  void clear();
  void finish() { clear(); }
  bool enabled() const { return enabled_; }

 private:
  long total_;
  long done_ = 0;
  bool enabled_;
  std::string unit_, label_;
  int drawn_ = 0;  // characters of the line on the terminal
  std::chrono::steady_clock::time_point start_, last_;
};

// note() with a Progress bar on the terminal: erases the bar first.
void note(Progress& progress, const std::string& message);

std::string join_argv(int argc, char** argv);

// SIGINT, SIGTERM and SIGHUP during a run (docs/cli.md "Signals"). The handler only
// counts the signal and writes its number to a pipe (async-signal-safe); a watcher
// thread reads the pipe and calls `on_signal(count, name)` outside the handler, where
// it may lock, write the file and _exit(). stop_requested(): a signal came (checked
// by the run between steps). Handlers are restored when the watch ends.
class SignalWatch {
 public:
  explicit SignalWatch(std::function<void(int count, const char* name)> on_signal);
  ~SignalWatch();
  SignalWatch(const SignalWatch&) = delete;
  SignalWatch& operator=(const SignalWatch&) = delete;
  static bool stop_requested();

 private:
  struct Impl;
  Impl* impl_;
};

// "a, b,c" -> {"a", "b", "c"} (core/text.hpp: the library's, shared with the Python module).
using softdiff::split_list;

}  // namespace softdiff::app
