// See threads.hpp.
#include <softdiff/core/threads.hpp>

#include <dlfcn.h>
#include <omp.h>

#include <algorithm>

namespace softdiff {

namespace {

// Measured (docs/performance.md "Threads"): below it one thread factorizes faster.
constexpr double kParallelFactorizationFlops = 1e9;

// OpenBLAS's API, looked up in the loaded libraries: the BLAS is chosen by Debian's
// alternatives (or an LD_PRELOAD), so it is not known at link time.
struct OpenBlasApi {
  void (*set_num_threads)(int) = nullptr;
  int (*get_num_threads)() = nullptr;
  char* (*get_config)() = nullptr;
  OpenBlasApi() {
    set_num_threads = reinterpret_cast<void (*)(int)>(dlsym(RTLD_DEFAULT, "openblas_set_num_threads"));
    get_num_threads = reinterpret_cast<int (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
    get_config = reinterpret_cast<char* (*)()>(dlsym(RTLD_DEFAULT, "openblas_get_config"));
  }
};

const OpenBlasApi& openblas() {
  static const OpenBlasApi api;
  return api;
}

}  // namespace

ThreadPlan thread_plan() {
  ThreadPlan plan;
  plan.threads = omp_get_max_threads();
  const auto& api = openblas();
  plan.openblas = api.set_num_threads != nullptr;
  plan.blas_threads = api.get_num_threads ? api.get_num_threads() : 1;
  plan.blas = api.get_config ? std::string(api.get_config()) : std::string("reference");
  return plan;
}

int plan_threads() { return omp_get_max_threads(); }

ThreadPlan set_threads(int n) {
  if (n <= 0) n = omp_get_max_threads();
  omp_set_num_threads(n);
  if (const auto& api = openblas(); api.set_num_threads) api.set_num_threads(n);
  return thread_plan();
}

void use_blas_threads(int n) {
  const auto& api = openblas();
  if (api.set_num_threads && api.get_num_threads && api.get_num_threads() != n) api.set_num_threads(n);
}

int factorization_threads(double flops) {
  return flops >= kParallelFactorizationFlops ? std::max(1, omp_get_max_threads()) : 1;
}

// Inside a parallel region nested regions are already serial (max-active-levels is
// 1 unless a user asks for nesting), and the process-wide setting must not be
// changed from several threads: the guard then does nothing.
SerialOpenMP::SerialOpenMP() : saved_(omp_in_parallel() ? -1 : omp_get_max_active_levels()) {
  if (saved_ >= 0) omp_set_max_active_levels(0);
}
SerialOpenMP::~SerialOpenMP() {
  if (saved_ >= 0) omp_set_max_active_levels(saved_);
}

}  // namespace softdiff
