#include "commands.hpp"

#include <softdiff/integrator/linear_solver.hpp>
#include <softdiff/io/hdf5_writer.hpp>
#include <softdiff/version.hpp>

#include <Eigen/Core>
#include <fcl/config.h>
#include <nlopt.hpp>
#include <yaml-cpp/yaml.h>

namespace softdiff::app {

std::string version_text() {
  int major = 0, minor = 0, bugfix = 0;
  nlopt::version(major, minor, bugfix);
  std::string s = "softdiff " SOFTDIFF_VERSION "\n";
  s += "  Eigen " + std::to_string(EIGEN_WORLD_VERSION) + "." + std::to_string(EIGEN_MAJOR_VERSION) + "." +
       std::to_string(EIGEN_MINOR_VERSION) + "\n";
  s += "  SuiteSparse " + integrator::suitesparse_version() + "\n";
  s += "  FCL " FCL_VERSION "\n";
  s += "  HDF5 " + io::hdf5_version() + "\n";
  s += "  NLopt " + std::to_string(major) + "." + std::to_string(minor) + "." + std::to_string(bugfix) + "\n";
  // The instruction set the build targets (docs/performance.md "Portable builds").
#if defined(__AVX512F__)
  s += "  built for this machine's CPU (-DSOFTDIFF_NATIVE=ON): AVX-512";
#elif defined(__AVX2__)
  s += "  built for this machine's CPU (-DSOFTDIFF_NATIVE=ON): AVX2";
#elif defined(__AVX__)
  s += "  built for this machine's CPU (-DSOFTDIFF_NATIVE=ON): AVX";
#else
  s += "  built for every x86-64 CPU (portable)";
#endif
  s += ", Eigen alignment " + std::to_string(EIGEN_MAX_ALIGN_BYTES) + " bytes";
  return s;
}

}  // namespace softdiff::app
