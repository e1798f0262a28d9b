#pragma once
// Wall-clock timing of pipeline stages (reports only; never asserted in tests).
#include <chrono>

namespace softdiff {

using Clock = std::chrono::steady_clock;
inline double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

}  // namespace softdiff
