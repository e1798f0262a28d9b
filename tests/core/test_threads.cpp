// The thread plan (core/threads.hpp): --threads reaches OpenMP and OpenBLAS, and
// CHOLMOD's own OpenMP loops run on one thread.
#include <softdiff/core/threads.hpp>

#include <gtest/gtest.h>
#include <omp.h>

namespace softdiff_test_threads {

// Threads that took part in a parallel region asking for `ask` threads.
int team_size(int ask) {
  int n = 0;
#pragma omp parallel num_threads(ask)
  {
#pragma omp single
    n = omp_get_num_threads();
  }
  return n;
}

TEST(ThreadPlan, SetThreadsReachesOpenMpAndOpenBlas) {
  const softdiff::ThreadPlan before = softdiff::thread_plan();
  for (const int n : {1, 2}) {
    const softdiff::ThreadPlan plan = softdiff::set_threads(n);
    EXPECT_EQ(plan.threads, n);
    EXPECT_EQ(omp_get_max_threads(), n);
    // The project pins OpenBLAS (CMake's SOFTDIFF_BLAS_DIR); its pool follows the plan.
    if (plan.openblas) {
      EXPECT_EQ(plan.blas_threads, n) << plan.blas;
    }
  }
  softdiff::set_threads(before.threads);
}

TEST(ThreadPlan, DefaultIsOpenMpsDefault) {
  const int before = omp_get_max_threads();
  EXPECT_EQ(softdiff::set_threads(0).threads, before);
}

// CHOLMOD 5.12 asks for num_threads(4) whatever omp_set_num_threads says; inside the
// guard such a region runs on one thread, and the setting returns afterwards.
TEST(ThreadPlan, SerialOpenMpGuardSerializesExplicitTeamSizes) {
  const int levels = omp_get_max_active_levels();
  ASSERT_GE(team_size(4), 2) << "OpenMP gave one thread without the guard: the test cannot tell";
  {
    softdiff::SerialOpenMP guard;
    EXPECT_EQ(team_size(4), 1);
  }
  EXPECT_EQ(omp_get_max_active_levels(), levels);
  EXPECT_GE(team_size(4), 2);
}

// Inside a parallel region the guard leaves the process-wide setting alone.
TEST(ThreadPlan, SerialOpenMpGuardInsideARegionChangesNothing) {
  const int levels = omp_get_max_active_levels();
  int seen = -2;
#pragma omp parallel num_threads(2)
  {
#pragma omp single
    {
      softdiff::SerialOpenMP guard;
      seen = omp_get_max_active_levels();
    }
  }
  EXPECT_EQ(seen, levels);
  EXPECT_EQ(omp_get_max_active_levels(), levels);
}

}  // namespace softdiff_test_threads
