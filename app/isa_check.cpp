// The instruction-set check of a build for the build machine's CPU
// (-DSOFTDIFF_NATIVE=ON, docs/performance.md "Portable builds").
//
// Such a build may execute AVX2 or AVX-512 instructions anywhere, so a binary built on
// one machine and run on an older one (a cluster's login node and its compute nodes)
// would die of SIGILL at an arbitrary point. This constructor runs before any other
// static initializer of the executable (priority 101), is compiled for baseline x86-64
// (the target attribute), and stops with a message naming the missing extension.
// The default build targets baseline x86-64 and defines none of these macros.
#include <cstdio>
#include <cstdlib>

#if defined(__x86_64__) && defined(__GNUC__) && (defined(__AVX__) || defined(__AVX2__) || defined(__AVX512F__))
namespace {

__attribute__((constructor(101), target("arch=x86-64"))) void softdiff_check_instruction_set() {
  __builtin_cpu_init();
  const char* missing = nullptr;
#if defined(__AVX512F__)
  if (!__builtin_cpu_supports("avx512f")) missing = "AVX-512 (avx512f)";
#endif
#if defined(__AVX2__)
  if (!missing && !__builtin_cpu_supports("avx2")) missing = "AVX2";
#endif
#if defined(__FMA__)
  if (!missing && !__builtin_cpu_supports("fma")) missing = "FMA";
#endif
#if defined(__AVX__)
  if (!missing && !__builtin_cpu_supports("avx")) missing = "AVX";
#endif
  if (missing) {
    std::fprintf(stderr,
                 "softdiff: this softdiff was built for the CPU of the machine that compiled it "
                 "(-DSOFTDIFF_NATIVE=ON), which has %s; this CPU does not. Rebuild it on this machine, or "
                 "configure with -DSOFTDIFF_NATIVE=OFF (the default) for a build that runs on every x86-64 CPU.\n",
                 missing);
    std::_Exit(1);
  }
}

}  // namespace
#endif
