#pragma once
// Calibration targets for the tests: every frame 1..steps of a run of the model.
#include <softdiff/core/error.hpp>
#include <softdiff/data.hpp>
#include <softdiff/integrator/implicit_euler.hpp>
#include <softdiff/optim/calibration.hpp>

#include <gtest/gtest.h>

#include <utility>

namespace softdiff::test {

inline optim::CalibrationTarget every_frame_target(const Model& model, long steps) {
  optim::CalibrationTarget t;
  Data data(model);
  State s = model.initial, next;
  for (long k = 1; k <= steps; ++k) {
    const StepStatus st = integrator::implicit_euler_step(model, data, s, next, k);
    EXPECT_TRUE(st.ok()) << describe(model, st);
    std::swap(s, next);
    t.frames.push_back(k);
    t.states.push_back(s.x);
  }
  return t;
}

}  // namespace softdiff::test
