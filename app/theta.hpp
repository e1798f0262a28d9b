#pragma once
// The theta lists of `simulate --jacobian` and `check-grad --wrt`: the library's
// (diff/theta_selection.hpp, shared with the Python module), under the app's names.
#include <softdiff/diff/theta_selection.hpp>

namespace softdiff::app {

using diff::parse_theta;
using diff::rigid_row_name;
using diff::ThetaGroup;
using diff::ThetaSelection;

}  // namespace softdiff::app
