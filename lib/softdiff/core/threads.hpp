#pragma once
// The thread plan (docs/performance.md "Threads"): who runs on how many threads.
//
// Three thread pools meet in a step: softdiff's OpenMP loops over elements, CHOLMOD's
// own OpenMP loops inside the supernodal factorization, and OpenBLAS's pthreads
// inside the dense kernels of each supernode. Left alone they oversubscribe the
// cores: Debian's CHOLMOD 5.12 asks for num_threads(CHOLMOD_OMP_NUM_THREADS), a
// compile-time 4, whatever omp_set_num_threads says, and OpenBLAS sizes its pool from
// the environment once, at load time. The plan, chosen by measurement:
//   - softdiff's OpenMP loops run on N threads;
//   - OpenBLAS runs on N threads (openblas_set_num_threads, found at run time, so a
//     reference BLAS simply has no pool);
//   - CHOLMOD's own OpenMP loops run on one thread (SerialOpenMP around every CHOLMOD
//     call): they only clear and scatter memory, and their forks cost more than they
//     save; the factorization's parallel work is OpenBLAS's.
// N is --threads, or by default OpenMP's own default: OMP_NUM_THREADS, else the cores
// in the process's CPU affinity (so that a Slurm or taskset allocation is respected).

#include <string>

namespace softdiff {

struct ThreadPlan {
  int threads = 1;       // softdiff's OpenMP loops
  int blas_threads = 1;  // OpenBLAS's pool (1 when the BLAS has none)
  bool openblas = false; // the loaded BLAS is OpenBLAS (it has a thread pool)
  std::string blas;      // the BLAS's own description (openblas_get_config), or "reference"
};

// Applies the plan for n threads (n <= 0: omp_get_max_threads()) and returns it.
ThreadPlan set_threads(int n);

// The plan in force (set_threads's last result; before any call, what the libraries
// chose from the environment).
ThreadPlan thread_plan();
// Its `threads` alone, without the BLAS's description (a string): cheap enough per step.
int plan_threads();

// RAII: OpenMP regions opened while it lives run on one thread (max-active-levels 0),
// then the previous setting returns. Used around CHOLMOD calls. Not for use inside a
// parallel region (the setting is process-wide in libgomp).
// OpenBLAS's pool on n threads from now on (nothing with a BLAS that has no pool).
// Not restored afterwards: growing the pool again wakes threads that then spin.
void use_blas_threads(int n);

// Threads for a sparse Cholesky factorization of `flops` floating-point operations
// (CHOLMOD's estimate from the analysis): the plan's threads above a measured size,
// one below it, where OpenBLAS's pool costs more to wake and to quiet than it saves
// (docs/performance.md "Threads").
int factorization_threads(double flops);

class SerialOpenMP {
 public:
  SerialOpenMP();
  ~SerialOpenMP();
  SerialOpenMP(const SerialOpenMP&) = delete;
  SerialOpenMP& operator=(const SerialOpenMP&) = delete;

 private:
  int saved_;
};

}  // namespace softdiff
