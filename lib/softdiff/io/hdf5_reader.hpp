#pragma once
// Reading HDF5 files back: a softdiff output's `status` (hdf5_writer.hpp, finish) and its
// datasets, groups and numeric attributes, for `softdiff sweep` and `softdiff collect`
// (docs/cli.md "sweep and collect"). Read-only, and forgiving: a missing file, object
// or attribute is an absent result (nullopt, empty), never an exception, and HDF5's
// error stack is not printed. Only std types here (STYLE.md section 1): HDF5 stays in
// hdf5_reader.cpp.
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace softdiff::io {

// The root attribute `status` of an HDF5 output ("running", "complete",
// "interrupted", "diverged: ...", "failed: ...": docs/output.md), as the writer writes
// it: a variable-length string. nullopt when `file` is not a regular file, is not an
// HDF5 file, or has no such attribute (or one of another type).
std::optional<std::string> read_status(const std::filesystem::path& file);

// An HDF5 file opened read-only (closed by the destructor). Paths are absolute HDF5
// paths ("/bodies/beam/x").
class Hdf5Reader {
 public:
  // Never throws: ok() is false when the file cannot be opened as HDF5.
  explicit Hdf5Reader(const std::filesystem::path& file);
  ~Hdf5Reader();
  Hdf5Reader(const Hdf5Reader&) = delete;
  Hdf5Reader& operator=(const Hdf5Reader&) = delete;

  bool ok() const;
  // Whether `path` names a link in the file (its parent groups must exist; false if not).
  bool exists(const std::string& path) const;
  // The whole dataset converted to float64, row-major (C order), and in `shape` its
  // dimensions (rank 0 for a scalar). Empty, with `shape` untouched, when the dataset
  // is absent or not numeric.
  std::vector<double> read(const std::string& path, std::vector<std::size_t>* shape = nullptr) const;
  // The names of a group's members in creation order (else by name, for a group
  // that does not track creation order). Empty when the group is absent.
  std::vector<std::string> members(const std::string& group) const;
  // The integer and float attributes of an object (a group, a dataset, "/" for the
  // root), converted to float64, in creation order (else by name). Text attributes
  // are skipped. Empty when the object is absent.
  std::vector<std::pair<std::string, double>> numeric_attributes(const std::string& object) const;

 private:
  std::int64_t file_ = -1;  // HDF5's file identifier (an int64_t since HDF5 1.10; checked in the .cpp)
};

}  // namespace softdiff::io
