#pragma once
// The SI units of the output datasets: the library's (io/units.hpp, moved there on
// 2026-12-04, branch pyout, with the run that writes them), under the app's names.
#include <softdiff/io/units.hpp>

namespace softdiff::app {

using io::actuator_measure_unit;
using io::actuator_value_unit;
using io::column_units;
using io::parameter_unit;
using io::position_per;

}  // namespace softdiff::app
