#pragma once
// Numbers in messages: `digits` significant digits, the stream's default notation
// (shortest of fixed and scientific), as every error message of the library prints them.
#include <sstream>
#include <string>

namespace softdiff {

inline std::string format_number(double value, int digits) {
  std::ostringstream s;
  s.precision(digits);
  s << value;
  return s.str();
}

}  // namespace softdiff
