// Target files of `softdiff calibrate`: see target_files.hpp.
#include <softdiff/io/target_files.hpp>

#include <softdiff/core/error.hpp>

#include <hdf5.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <sstream>

namespace softdiff::io {

namespace {

[[noreturn]] void fail(const std::filesystem::path& file, const std::string& message) {
  throw InputError(file.string() + ": " + message);
}

// Closes an HDF5 handle on scope exit.
struct Handle {
  hid_t id = -1;
  herr_t (*close)(hid_t) = nullptr;
  ~Handle() {
    if (id >= 0 && close) close(id);
  }
};

// A float64 dataset's shape and values; fails with the dataset's name.
std::vector<double> read_dataset(const std::filesystem::path& file, hid_t f, const std::string& path,
                                 std::vector<hsize_t>& dims) {
  if (H5Lexists(f, path.c_str(), H5P_DEFAULT) <= 0) fail(file, "no dataset " + path + " (is it a softdiff trajectory?)");
  Handle d{H5Dopen2(f, path.c_str(), H5P_DEFAULT), H5Dclose};
  if (d.id < 0) fail(file, path + " is not a dataset");
  Handle s{H5Dget_space(d.id), H5Sclose};
  const int rank = H5Sget_simple_extent_ndims(s.id);
  dims.assign(static_cast<std::size_t>(std::max(rank, 0)), 0);
  H5Sget_simple_extent_dims(s.id, dims.data(), nullptr);
  Handle t{H5Dget_type(d.id), H5Tclose};
  if (H5Tget_class(t.id) != H5T_FLOAT) fail(file, path + ": expected float64 values");
  hsize_t count = 1;
  for (hsize_t v : dims) count *= v;
  std::vector<double> values(count);
  if (count > 0 && H5Dread(d.id, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()) < 0)
    fail(file, path + ": cannot be read");
  for (double v : values)
    if (!std::isfinite(v)) fail(file, path + ": holds a non-finite value");
  return values;
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}

std::vector<std::string> fields(const std::string& line) {
  std::vector<std::string> out;
  std::stringstream in(line);
  std::string item;
  while (std::getline(in, item, ',')) out.push_back(trim(item));
  if (!line.empty() && line.back() == ',') out.push_back("");
  return out;
}

bool parse_double(const std::string& s, double& v) {
  if (s.empty()) return false;
  std::size_t used = 0;
  try {
    v = std::stod(s, &used);
  } catch (...) {
    return false;
  }
  return used == s.size() && std::isfinite(v);
}

}  // namespace

TrajectoryFile read_trajectory(const std::filesystem::path& file, const Model& model) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) fail(file, "no such file");
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
  if (H5Fis_hdf5(file.c_str()) <= 0) fail(file, "not an HDF5 file (expected a softdiff trajectory, docs/output.md)");
  Handle f{H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose};
  if (f.id < 0) fail(file, "cannot be opened");
  TrajectoryFile out;
  std::vector<hsize_t> dims;
  out.times = read_dataset(file, f.id, "/time", dims);
  if (dims.size() != 1) fail(file, "/time: expected a 1-D dataset");
  const std::size_t T = out.times.size();
  if (T == 0) fail(file, "/time: no frame");
  for (std::size_t k = 1; k < T; ++k)
    if (!(out.times[k] > out.times[k - 1])) fail(file, "/time: times must increase (frame " + std::to_string(k) + ")");
  out.x.assign(T, VecX::Zero(3L * model.fem.num_nodes));
  for (const auto& b : model.fem.bodies) {
    const std::string path = "/bodies/" + b.name + "/x";
    if (H5Lexists(f.id, ("/bodies/" + b.name).c_str(), H5P_DEFAULT) <= 0)
      fail(file, "no body '" + b.name + "' (the scene's bodies must be in the target trajectory)");
    const std::vector<double> x = read_dataset(file, f.id, path, dims);
    if (dims.size() != 3 || dims[0] != T || dims[1] != static_cast<hsize_t>(b.num_nodes) || dims[2] != 3) {
      std::ostringstream s;
      s << path << ": expected shape (" << T << ", " << b.num_nodes << ", 3) (the scene's body '" << b.name
        << "' has " << b.num_nodes << " nodes), got (";
      for (std::size_t i = 0; i < dims.size(); ++i) s << (i ? ", " : "") << dims[i];
      s << ")";
      fail(file, s.str());
    }
    for (std::size_t k = 0; k < T; ++k)
      out.x[k].segment(3L * b.node_begin, 3L * b.num_nodes) =
          Eigen::Map<const VecX>(x.data() + k * 3 * static_cast<std::size_t>(b.num_nodes), 3L * b.num_nodes);
  }
  // Rigid bodies' poses (issue 21): matched where the file has them.
  for (std::size_t r = 0; r < model.rigid.size(); ++r) {
    const std::string name = model.rigid[r].name, group = "/bodies/" + name;
    const auto exists = [&](const std::string& path) {
      return H5Lexists(f.id, "/bodies", H5P_DEFAULT) > 0 && H5Lexists(f.id, group.c_str(), H5P_DEFAULT) > 0 &&
             H5Lexists(f.id, path.c_str(), H5P_DEFAULT) > 0;
    };
    const bool has_p = exists(group + "/position"), has_q = exists(group + "/orientation");
    if (!has_p && !has_q) {
      out.rigid_missing.push_back(name);
      continue;
    }
    if (has_p != has_q)
      fail(file, group + (has_p ? "/position" : "/orientation") + " without " + group +
                     (has_p ? "/orientation" : "/position") + ": a rigid body's pose needs both (docs/output.md)");
    const auto read = [&](const std::string& path, hsize_t width, const std::string& what) {
      const std::vector<double> v = read_dataset(file, f.id, path, dims);
      if (dims.size() != 2 || dims[0] != T || dims[1] != width) {
        std::ostringstream s;
        s << path << ": expected shape (" << T << ", " << width << ") (" << what << " of the scene's rigid body '" << name
          << "' at each of the " << T << " frames of /time), got (";
        for (std::size_t i = 0; i < dims.size(); ++i) s << (i ? ", " : "") << dims[i];
        s << ")";
        fail(file, s.str());
      }
      return v;
    };
    const std::vector<double> p = read(group + "/position", 3, "the centre of mass");
    const std::vector<double> q = read(group + "/orientation", 4, "the unit quaternion w, x, y, z");
    TrajectoryFile::RigidTrajectory rt;
    rt.body = static_cast<int>(r);
    for (std::size_t k = 0; k < T; ++k) {
      rt.position.emplace_back(p[3 * k], p[3 * k + 1], p[3 * k + 2]);
      Eigen::Quaterniond qk(q[4 * k], q[4 * k + 1], q[4 * k + 2], q[4 * k + 3]);
      if (!(std::abs(qk.norm() - 1) <= 1e-6)) {
        std::ostringstream s;
        s << group << "/orientation: frame " << k << " is not a unit quaternion (norm " << qk.norm() << ")";
        fail(file, s.str());
      }
      qk.normalize();
      rt.orientation.push_back(qk);
    }
    out.rigid.push_back(std::move(rt));
  }
  return out;
}

std::vector<MarkerObservation> read_markers(const std::filesystem::path& file) {
  std::ifstream in(file);
  if (!in) fail(file, "cannot be opened");
  std::vector<MarkerObservation> out;
  std::string line;
  int number = 0;
  bool header = false;
  while (std::getline(in, line)) {
    ++number;
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    const std::vector<std::string> f = fields(t);
    const std::string where = file.string() + ":" + std::to_string(number) + ": ";
    if (!header) {
      std::string lower = t;
      std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char c) { return std::tolower(c); });
      std::vector<std::string> h = fields(lower);
      if (h != std::vector<std::string>{"time", "marker", "x", "y", "z"})
        throw InputError(where + "expected the header line 'time,marker,x,y,z', got '" + t + "'");
      header = true;
      continue;
    }
    if (f.size() != 5)
      throw InputError(where + "expected 5 comma-separated fields (time, marker, x, y, z), got " +
                       std::to_string(f.size()));
    MarkerObservation o;
    o.line = number;
    if (!parse_double(f[0], o.time) || o.time < 0)
      throw InputError(where + "time: expected a number >= 0, got '" + f[0] + "'");
    if (f[1].empty()) throw InputError(where + "marker: expected a name, got nothing");
    o.marker = f[1];
    for (int c = 0; c < 3; ++c)
      if (!parse_double(f[2 + c], o.position[c]))
        throw InputError(where + std::string(1, "xyz"[c]) + ": expected a finite number, got '" + f[2 + c] + "'");
    out.push_back(o);
  }
  if (!header) fail(file, "empty (expected the header line 'time,marker,x,y,z' and observations)");
  if (out.empty()) fail(file, "no observation after the header");
  return out;
}

}  // namespace softdiff::io
