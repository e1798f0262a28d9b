// Compiled by tests/collision/fcl_abi_guard.sh under several instruction sets: the
// layout check of lib/softdiff/collision/fcl.hpp must pass with softdiff's Eigen
// alignment pin and fail without it on AVX-512.
#include <softdiff/collision/fcl.hpp>

int main() { return 0; }
