#pragma once
// Target files of `softdiff calibrate` (docs/cli.md): a softdiff trajectory (HDF5,
// docs/output.md) and a marker CSV. Every problem is an InputError naming the file,
// the place in it (dataset, line) and what was expected.
#include <softdiff/core/types.hpp>
#include <softdiff/model.hpp>

#include <Eigen/Geometry>

#include <filesystem>
#include <string>
#include <vector>

namespace softdiff::io {

// The positions of a softdiff trajectory for the bodies of `model`: times (T) and, per
// frame, x (3 n_total, body order). Checks that every body of the model is in the file
// with the model's node count (a target made with another mesh is an error).
//
// Rigid bodies (issue 21): a rigid body of the model whose /bodies/<r>/position (T, 3)
// and /bodies/<r>/orientation (T, 4: w, x, y, z, unit within 1e-6, normalized) are in the
// file is in `rigid`; one without either dataset is in `rigid_missing` (not matched);
// a body with only one of them, or with a wrong shape, is an error.
struct TrajectoryFile {
  std::vector<double> times;
  std::vector<VecX> x;
  struct RigidTrajectory {
    int body = 0;  // Model::rigid index
    std::vector<Vec3> position;                   // per frame
    std::vector<Eigen::Quaterniond> orientation;  // per frame
  };
  std::vector<RigidTrajectory> rigid;
  std::vector<std::string> rigid_missing;  // the rigid bodies not in the file
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
