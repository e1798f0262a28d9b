#pragma once
// Streaming HDF5 output (spec: docs/output.md) and the XDMF files beside it.
//
// The file is written under a temporary name (`<file>.partial`) and moved to its
// place by finish(). Frames are appended to chunked, extendible datasets and the file
// is flushed every `flush_every` frames, so a run that dies leaves every completed
// frame readable. An existing final file is never overwritten unless `force`, and
// even then only by a complete run: an unfinished one ("interrupted", "diverged: ...",
// "failed: ...") goes to a side file named by its kind (out.h5 -> out.interrupted.h5).
//
// Disk space: before each frame the writer reserves room beyond the end of the file
// (fallocate, FALLOC_FL_KEEP_SIZE: no size change, released when the file is closed)
// for that frame and for finishing the file. When the disk cannot give it, the frame
// is refused (ComputationError, failure() = "No space left on device") before any of
// it is written, so that the file can still be given its status and closed.
//
// Errors: HDF5 failures while writing (disk full, quota, I/O error) throw
// ComputationError naming the file, the dataset and the system's reason; a frame
// or row that fails is not written (every per-frame dataset keeps the same T) and
// the writer stays usable. Misuse (wrong sizes, unknown or existing paths, calls
// after finish) throws std::logic_error. The XDMF layout is described in xdmf.hpp.
#include <softdiff/core/types.hpp>

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <variant>
#include <vector>

namespace softdiff::io {

struct OutputBody {
  std::string name;
  Mat3X rest;           // (3, n) rest positions (after scale/rotate/translate)
  Eigen::MatrixXi tets;     // (4, m), or (10, m) for a quadratic body (gmsh's node order)
  Eigen::MatrixXi surface;  // (3, k) outward boundary triangles, or (6, k) 6-node ones (gmsh's order)
};

struct WriterOptions {
  std::filesystem::path file;
  bool force = false;
  bool write_v = false;
  // /bodies/<b>/contact_force (T, n, 3): the nodal contact forces given to append_frame.
  bool write_contact_force = false;
  // 0: no compression; 1..9: the per-frame node datasets (x, v, displacement,
  // contact_force) are stored shuffled and deflated at this level, one frame per chunk.
  int gzip_level = 0;
  std::string command;      // argv joined with spaces
  std::string scene_yaml;   // whole scene text
  int flush_every = 10;     // frames
};

// A typed attribute: text, a float64 or an int64 (counts, indices, flags).
using AttributeValue = std::variant<std::string, double, std::int64_t>;
struct Attribute {
  std::string name;
  AttributeValue value;
};

class Hdf5Writer {
 public:
  // Throws InputError if the file exists and !force, or if its folder does not
  // exist / is not writable. Nothing is left on disk when it throws.
  Hdf5Writer(const WriterOptions& options, const std::vector<OutputBody>& bodies);
  ~Hdf5Writer();  // finish("failed: the run ended with an error") if finish() was not called; never throws
  Hdf5Writer(const Hdf5Writer&) = delete;
  Hdf5Writer& operator=(const Hdf5Writer&) = delete;

  // Appends one frame. x (and v when write_v, contact_force when
  // write_contact_force) hold all bodies' nodes in body order, node-major
  // (3 * n_total). step_seconds: wall time of the step that produced the frame (0
  // for frame 0). Also writes the frame's displacement x - rest.
  void append_frame(double time, const VecX& x, const VecX* v, double step_seconds,
                    const VecX* contact_force = nullptr);

  // Every dataset carries a `units` attribute (SI: "m", "m/s", "N", "s", "Pa", "1"
  // for dimensionless values and indices); the dataset-creating calls take it.

  // Generic per-frame series for later stages (actuators, effectors, contact,
  // solver figures): a dataset at `path` of shape (T) when width == 0 or (T, width),
  // float64, appended one row per call. Returns a handle for append_series.
  int add_series(const std::string& path, int width, const std::string& units);
  void append_series(int handle, const double* row);

  // Ragged per-frame tables (e.g. /contact/*): a dataset of shape (N, row_shape...)
  // of the given element type that grows by any number of rows per call (rows
  // given row-major, of the element type: double, int64_t, int32_t, int8_t).
  enum class Element { f64, i64, i32, i8 };
  int add_table(const std::string& path, const std::vector<int>& row_shape, Element type, const std::string& units);
  void append_rows(int handle, const void* rows, long count);
  // A 1-D dataset of variable-length UTF-8 strings, written once.
  void write_strings(const std::string& path, const std::vector<std::string>& values, const std::string& units);

  // A dense matrix written once (e.g. /jacobians/<theta>), with typed attributes.
  // `units`: one unit, or one per column comma-separated when the columns differ.
  void write_matrix(const std::string& path, const MatX& value, const std::string& units,
                    const std::vector<Attribute>& attributes = {});
  // Attribute on the root or on any existing group or dataset.
  void set_attribute(const std::string& object_path, const std::string& name, const std::string& value);
  void set_attribute(const std::string& object_path, const std::string& name, const char* value);
  void set_attribute(const std::string& object_path, const std::string& name, double value);
  void set_attribute(const std::string& object_path, const std::string& name, std::int64_t value);
  void set_attribute(const std::string& object_path, const std::string& name, int value);

  // Writes the `status` attribute, closes the file and moves it to its place:
  // - "complete": the final name (with force, replacing an existing file; without,
  //   InputError if a file of that name appeared meanwhile: the frames stay in
  //   <file>.partial);
  // - any other status: the final name when no file of that name exists, else the
  //   side file side_file_name(file, kind) (kind: the status up to its ':'); also the
  //   side file "failed" when the status could not be written (the file says running).
  // The XDMF file goes beside it. final_path() then names the file holding the frames.
  // Idempotent. Every step is tried; then ComputationError if the status could not
  // be written, the file closed or moved (the message says where the frames are).
  void finish(const std::string& status);

  long frames_written() const;
  // The output file's name; after finish(), the file that holds the frames.
  const std::filesystem::path& final_path() const;
  // The system's reason for the last failed write ("No space left on device"), or "".
  const std::string& failure() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// out.h5 -> out.<kind>.h5 (kind: interrupted, diverged, failed): where an unfinished
// run goes when it must not take the output's name.
std::filesystem::path side_file_name(const std::filesystem::path& file, const std::string& kind);
// Every file a writer of `file` may create or replace: the file, <file>.partial, its
// XDMF files (out.xmf, and out.<body>.xmf for each of `body_names`) and the side files
// with their XDMF files.
std::vector<std::filesystem::path> output_file_names(const std::filesystem::path& file,
                                                     const std::vector<std::string>& body_names = {});

// The bytes a run of `frames` frames writes (at least): the bodies' rest, tets and
// surface, per frame x, the displacement (and v, the nodal contact force), the frame
// views, /time, /solver/step_seconds and `series_per_frame` more bytes, plus the XDMF
// files. Contact rows (their number is not known) are not counted.
struct OutputEstimate {
  double hdf5_bytes = 0, xdmf_bytes = 0, frame_bytes = 0;
  double total() const { return hdf5_bytes + xdmf_bytes; }
};
OutputEstimate estimate_output(const std::vector<OutputBody>& bodies, bool write_v, bool write_contact_force,
                               long frames, double series_per_frame, const std::string& h5_name);

// True once an HDF5 file could not be closed (the disk was full): HDF5's own exit
// handler would then crash on the half-closed file, so the program must leave with
// _exit() (softdiff's main does).
bool hdf5_close_failed();

// Library versions for `softdiff --version` and the file's attributes.
std::string hdf5_version();

}  // namespace softdiff::io
