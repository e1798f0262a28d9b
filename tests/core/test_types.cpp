#include <softdiff/material/material.hpp>
#include <gtest/gtest.h>

TEST(Lame, FromYoungPoisson) {
  const auto l = softdiff::material::lame_from_young_poisson(1.0e5, 0.25);
  EXPECT_DOUBLE_EQ(l.mu, 1.0e5 / 2.5);
  EXPECT_DOUBLE_EQ(l.lambda, 1.0e5 * 0.25 / (1.25 * 0.5));
}
