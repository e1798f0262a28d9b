#pragma once
// Target files of `softdiff calibrate` (docs/cli.md): a softdiff trajectory (HDF5,
// docs/output.md) and a marker CSV. Every problem is an InputError naming the file,
// the place in it (dataset, line) and what was expected.
#include <softdiff/core/types.hpp>
#include <softdiff/model.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace softdiff::io {

// The positions of a softdiff trajectory for the bodies of `model`: times (T) and, per
// frame, x (3 n_total, body order). Checks that every body of the model is in the file
// with the model's node count (a target made with another mesh is an error).
struct TrajectoryFile {
  std::vector<double> times;
  std::vector<VecX> x;
};
TrajectoryFile read_trajectory(const std::filesystem::path& file, const Model& model);

// A marker CSV: a header line `time,marker,x,y,z` (any case, spaces allowed), then one
// observation per line: time (s, >= 0), marker name, position (m). Blank lines and
// lines starting with '#' are skipped.
struct MarkerObservation {
  double time = 0;
  std::string marker;
  Vec3 position = Vec3::Zero();
  int line = 0;
};
std::vector<MarkerObservation> read_markers(const std::filesystem::path& file);

}  // namespace softdiff::io
