#pragma once
// Errors. Bad input (scene, mesh, target files, command line) is an InputError
// (exit code 2); a computation that fails (divergence, a matrix that is not
// positive definite, ...) is a ComputationError (exit code 1). Inner loops do not
// throw: they set a status that the caller turns into one of these.
#include <stdexcept>
#include <string>

namespace softdiff {

class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

class ComputationError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

}  // namespace softdiff
