#pragma once
// Shared helpers of the subcommands: messages, JSON output, progress bar, timers.
#include <chrono>
#include <cstdio>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <vector>

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

// Progress bar on stderr when it is a terminal (not on a pipe, not with --quiet).
class Progress {
 public:
  Progress(long total, bool enabled);
  void update(long done);
  void finish();

 private:
  long total_;
  bool enabled_;
  std::chrono::steady_clock::time_point start_, last_;
};

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

// "a, b,c" -> {"a", "b", "c"}: items trimmed of blanks; a trailing separator gives a
// last empty item (so that "young," is reported as an empty name).
std::vector<std::string> split_list(const std::string& s, char sep = ',');

}  // namespace softdiff::app
