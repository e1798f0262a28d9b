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
  s += "  NLopt " + std::to_string(major) + "." + std::to_string(minor) + "." + std::to_string(bugfix);
  return s;
}

}  // namespace softdiff::app
