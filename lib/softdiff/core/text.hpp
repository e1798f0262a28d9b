#pragma once
// Lists in option values: "young, poisson" -> {"young", "poisson"} (the CLI's
// --jacobian, --wrt, calibrate's lists, and the Python module's theta lists).
#include <string>
#include <vector>

namespace softdiff {

// "a, b,c" -> {"a", "b", "c"}: items trimmed of blanks; a trailing separator gives a
// last empty item (so that "young," is reported as an empty name).
std::vector<std::string> split_list(const std::string& s, char sep = ',');

}  // namespace softdiff
