// Streaming HDF5 output: see hdf5_writer.hpp and the format spec (output.md).
//
// Design notes
// - File format: HDF5's default (earliest) library-version bounds. Files are readable
//   by any HDF5 >= 1.8 (h5py, h5dump, ParaView), and a file left open by a killed
//   process carries no "file is open for writing" superblock flag (the 1.10 format
//   would), so readers open it without h5clear. The XDMF files' views
//   (/xdmf/..., HDF5 virtual datasets) are the one object that needs HDF5 >= 1.10
//   (the library raises the version of those objects alone; the superblock stays).
// - Frames: every per-frame dataset is chunked with an unlimited first dimension.
//   A frame of x/v that is at least 64 KiB is one chunk, written straight from the
//   caller's buffer (no chunk cache, no fill value: HDF5 then copies nothing).
//   Smaller frames are grouped several per chunk through the chunk cache.
// - Consistency: append_frame extends and writes every per-frame dataset; if any
//   write fails, all of them are shrunk back, so /time and every x always hold the
//   same T. The file is flushed every flush_every frames (and at finish), so a run
//   killed between flushes leaves a file readable up to the last flush.
// - Safety: the file is written as <file>.partial (created exclusively unless
//   force) and renamed at finish; without force the rename never replaces a file,
//   and an unfinished run never replaces one (it goes to a side file).
// - Disk space: fallocate(FALLOC_FL_KEEP_SIZE) reserves, before each frame, room
//   past HDF5's end of allocation (EOA) for that frame and for closing the file. The
//   file's size does not change (HDF5's end of file stays where it was) and the close
//   truncates the file to its EOA, which releases what was not used. A disk that fills
//   is met at the reservation, before any byte of the frame is written: the frames so
//   far, their status and the file's metadata still fit in what was reserved before.
//   A failed H5Fclose leaves HDF5 with a half-closed file on which its exit handler
//   crashes (H5F__close_cb): hdf5_close_failed() tells main to leave with _exit().
#include <softdiff/io/hdf5_writer.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>
#include <softdiff/io/xdmf.hpp>
#include <softdiff/version.hpp>

#include <fcntl.h>
#include <hdf5.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cctype>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <system_error>
#include <utility>

namespace softdiff::io {

namespace {

namespace fs = std::filesystem;

// ---------------------------------------------------------------------------
// HDF5 identifiers and errors

// Owns one HDF5 identifier and closes it with the matching H5?close.
class Handle {
 public:
  using Closer = herr_t (*)(hid_t);
  Handle() = default;
  Handle(hid_t id, Closer closer) : id_(id), closer_(closer) {}
  Handle(Handle&& other) noexcept : id_(std::exchange(other.id_, -1)), closer_(other.closer_) {}
  Handle& operator=(Handle&& other) noexcept {
    if (this != &other) {
      reset();
      id_ = std::exchange(other.id_, -1);
      closer_ = other.closer_;
    }
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { reset(); }

  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  // Closes now; false if HDF5 reported an error while closing.
  bool reset() {
    bool ok = true;
    if (id_ >= 0 && closer_ != nullptr) ok = closer_(id_) >= 0;
    id_ = -1;
    return ok;
  }

 private:
  hid_t id_ = -1;
  Closer closer_ = nullptr;
};

struct ErrorWalk {
  std::string innermost;
};

herr_t collect_error(unsigned /*n*/, const H5E_error2_t* error, void* data) {
  auto* walk = static_cast<ErrorWalk*>(data);
  if (error != nullptr && error->desc != nullptr && error->desc[0] != '\0') walk->innermost = error->desc;
  return 0;
}

// The reason for the HDF5 failure that just happened, from the innermost entry of
// HDF5's error stack (which is then cleared). An I/O failure carries errno's text:
// "file write failed: time = ..., errno = 28, error message = 'No space left on
// device', ..." becomes "file write failed: No space left on device".
std::string hdf5_reason() {
  ErrorWalk walk;
  H5Ewalk2(H5E_DEFAULT, H5E_WALK_DOWNWARD, collect_error, &walk);
  H5Eclear2(H5E_DEFAULT);
  std::string reason = walk.innermost;
  const std::string marker = "error message = '";
  if (const auto at = reason.find(marker); at != std::string::npos) {
    const auto start = at + marker.size();
    const auto end = reason.find('\'', start);
    const auto head = reason.find_first_of(":,");
    reason = reason.substr(0, head) + ": " + reason.substr(start, end == std::string::npos ? end : end - start);
  }
  return reason.empty() ? std::string("unknown HDF5 error") : reason;
}

void silence_hdf5_error_printing() {
  // HDF5 prints its error stack to stderr by default; we report errors as exceptions.
  H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
}

// ---------------------------------------------------------------------------
// Small helpers

std::string iso8601_utc_now() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

// Chunk of (rows, ...) for an appendable dataset whose rows hold `row_bytes` bytes:
// about `target_bytes` per chunk, at most `max_rows` rows.
hsize_t rows_per_chunk(std::size_t row_bytes, std::size_t target_bytes, hsize_t max_rows) {
  const std::size_t rows = target_bytes / std::max<std::size_t>(row_bytes, 1);
  return std::clamp<hsize_t>(static_cast<hsize_t>(rows), 1, max_rows);
}

constexpr std::size_t kFrameChunkBytes = 64 * 1024;    // below this, frames share chunks
constexpr std::size_t kSeriesChunkBytes = 32 * 1024;   // rows of a generic series
constexpr hsize_t kMaxChunkRows = 1024;
constexpr hsize_t kMaxChunkNodes = hsize_t{1} << 22;   // 96 MiB chunks at most

// Dataset access properties. `direct`: no chunk cache, so that a write covering
// whole chunks goes from the caller's buffer to the file (with no fill value, see
// create_appendable). Returns an invalid handle on failure.
Handle dataset_access(bool direct) {
  Handle access(H5Pcreate(H5P_DATASET_ACCESS), H5Pclose);
  if (access.valid() && direct &&
      H5Pset_chunk_cache(access.get(), H5D_CHUNK_CACHE_NSLOTS_DEFAULT, 0, H5D_CHUNK_CACHE_W0_DEFAULT) < 0)
    access.reset();
  return access;
}

// A dataset of shape (rows, d1[, d2]) that grows by one row (or by any number of
// rows, for tables) at a time. Float64 unless created as a table of another type.
struct Appendable {
  std::string path;
  bool direct = false;
  hid_t memory_type = H5T_NATIVE_DOUBLE;
  int rank = 1;
  std::array<hsize_t, 3> dims{0, 0, 0};  // dims[0]: rows written
  std::array<hsize_t, 3> row{1, 0, 0};   // shape of one row: (1, d1, d2)
  Handle dataset;
  Handle file_space;  // kept and re-extended, not re-created per row
  Handle memory_space;

  // Appends one row; false on an HDF5 failure (the error stack is left for the caller).
  bool append(const double* values) {
    std::array<hsize_t, 3> grown = dims;
    grown[0] += 1;
    const std::array<hsize_t, 3> start{dims[0], 0, 0};
    std::array<hsize_t, 3> max_dims = dims;
    max_dims[0] = H5S_UNLIMITED;
    if (H5Dset_extent(dataset.get(), grown.data()) < 0) return false;
    if (H5Sset_extent_simple(file_space.get(), rank, grown.data(), max_dims.data()) < 0) return false;
    if (H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr, row.data(), nullptr) < 0)
      return false;
    if (H5Dwrite(dataset.get(), memory_type, memory_space.get(), file_space.get(), H5P_DEFAULT, values) < 0)
      return false;
    dims = grown;
    return true;
  }

  // Appends `count` rows at once (count >= 1).
  bool append_rows(const void* values, hsize_t count) {
    std::array<hsize_t, 3> grown = dims;
    grown[0] += count;
    const std::array<hsize_t, 3> start{dims[0], 0, 0};
    std::array<hsize_t, 3> block = row;
    block[0] = count;
    std::array<hsize_t, 3> max_dims = dims;
    max_dims[0] = H5S_UNLIMITED;
    if (H5Dset_extent(dataset.get(), grown.data()) < 0) return false;
    if (H5Sset_extent_simple(file_space.get(), rank, grown.data(), max_dims.data()) < 0) return false;
    if (H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr, block.data(), nullptr) < 0)
      return false;
    Handle memory(H5Screate_simple(rank, block.data(), nullptr), H5Sclose);
    if (!memory.valid()) return false;
    if (H5Dwrite(dataset.get(), memory_type, memory.get(), file_space.get(), H5P_DEFAULT, values) < 0) return false;
    dims = grown;
    return true;
  }

  // Undoes a failed append: shrinks the dataset back to `rows` and reopens it. Best
  // effort. The reopening matters: when a chunk write fails, HDF5 1.10 keeps the
  // address of the chunk it had just allocated in the dataset's chunk lookup cache
  // although the chunk never entered the chunk index; the next write of that chunk
  // would go to that address without indexing it (the frame would read as zeros).
  void roll_back(hid_t file, hsize_t rows) {
    if (!dataset.valid()) return;
    std::array<hsize_t, 3> shape = dims;
    shape[0] = rows;
    H5Dset_extent(dataset.get(), shape.data());
    dims[0] = rows;
    dataset.reset();
    const Handle access = dataset_access(direct);
    dataset = Handle(H5Dopen2(file, path.c_str(), access.valid() ? access.get() : H5P_DEFAULT), H5Dclose);
  }

  bool close() {
    bool ok = memory_space.reset();
    ok = file_space.reset() && ok;
    return dataset.reset() && ok;
  }
};

struct BodyOutput {
  std::string name;
  Eigen::Index first_node = 0;  // offset in the global node-major x
  Eigen::Index nodes = 0;
  Eigen::Index tets = 0;
  Eigen::Index triangles = 0;  // surface triangles (the XDMF topology of a body without tets)
  int nodes_per_tet = 4;  // 4 or 10
  VecX rest;          // (3n) node-major rest positions
  VecX displacement;  // (3n) x - rest of the frame being appended (sized at creation)
  Appendable x, v, displacement_frames, contact_force;
};

bool exists_as_file_system_entry(const fs::path& path) {
  std::error_code ec;
  return fs::exists(fs::symlink_status(path, ec));
}

std::atomic<bool> g_close_failed{false};

// "file write failed: No space left on device" -> "No space left on device".
std::string system_part(const std::string& reason) {
  const auto at = reason.rfind(": ");
  return at == std::string::npos ? reason : reason.substr(at + 2);
}

constexpr double kReserveMinBytes = 1 << 20;  // reserved past the EOA, at least


}  // namespace

// ---------------------------------------------------------------------------

struct Hdf5Writer::Impl {
  WriterOptions options;
  fs::path final_file, partial_file, xdmf_file;
  std::vector<BodyOutput> bodies;
  Eigen::Index total_nodes = 0;
  Handle file;
  Appendable time, step_seconds;
  std::vector<Appendable> series;
  std::vector<double> times;
  long frames = 0;
  bool finished = false;
  fs::path written_file;              // after finish: the file holding the frames
  mutable std::string last_failure;   // the system's reason for the last failed write
  int fd = -1;                        // the file's descriptor (HDF5's sec2 driver), for fallocate
  bool reserve_supported = true;      // false where the file system has no fallocate
  double reserve_bytes = kReserveMinBytes;
  off_t reserve_end = 0;              // the end of the reserved range

  std::string partial_name() const { return partial_file.string(); }

  [[noreturn]] void fail(const std::string& what) const {
    const std::string reason = hdf5_reason();
    last_failure = system_part(reason);
    throw ComputationError(partial_name() + ": " + what + ": " + reason);
  }

  // Reserves `bytes` of disk past HDF5's end of allocation (see the design notes);
  // false when the disk has no room (errno ENOSPC or EDQUOT). True, reserving
  // nothing, where the file system has no fallocate.
  bool reserve_room(double bytes) {
    if (fd < 0 || !reserve_supported) return true;
    haddr_t eoa = 0;
    if (H5Fget_eoa(file.get(), &eoa) < 0) {
      H5Eclear2(H5E_DEFAULT);
      return true;
    }
    if (::fallocate(fd, FALLOC_FL_KEEP_SIZE, static_cast<off_t>(eoa), static_cast<off_t>(bytes)) == 0) {
      reserve_end = std::max(reserve_end, static_cast<off_t>(eoa) + static_cast<off_t>(bytes));
      return true;
    }
    if (errno == ENOSPC || errno == EDQUOT) return false;
    reserve_supported = false;  // EOPNOTSUPP and the like: write without a reserve
    return true;
  }

  // Closes the file; on failure, records it for hdf5_close_failed(). Then gives the
  // disk back what was reserved past the file's end and not used (blocks allocated
  // with FALLOC_FL_KEEP_SIZE stay allocated after the close otherwise).
  bool close_file() {
    const bool ok = close_everything();
    if (!ok) g_close_failed = true;
    fd = -1;
    if (reserve_end > 0) {
      const int f = ::open(partial_file.c_str(), O_WRONLY | O_CLOEXEC);
      struct stat st {};
      // Growing by a byte and shrinking back frees the blocks past the end (ext4
      // ignores FALLOC_FL_PUNCH_HOLE past the end of the file).
      if (f >= 0 && ::fstat(f, &st) == 0 && ::ftruncate(f, st.st_size + 1) == 0 && ::ftruncate(f, st.st_size) != 0)
        errno = 0;
      if (f >= 0) ::close(f);
      reserve_end = 0;
    }
    return ok;
  }

  // ---- creation

  void check_paths() {
    final_file = options.file;
    if (final_file.empty()) throw InputError("output file name is empty");
    partial_file = final_file;
    partial_file += ".partial";
    xdmf_file = final_file;
    xdmf_file.replace_extension(".xmf");
    const std::string name = final_file.string();
    if (xdmf_file == final_file)
      throw InputError(name + ": the output file cannot end in .xmf (the XDMF file is written beside it)");
    if (final_file.filename().string().find_first_of(":|") != std::string::npos)
      throw InputError(name + ": the output file name cannot contain ':' or '|' (the XDMF file beside it "
                       "could not reference it)");

    std::error_code ec;
    if (exists_as_file_system_entry(final_file)) {
      if (fs::is_directory(final_file, ec)) throw InputError(name + ": output file is a folder");
      if (!options.force) throw InputError(name + ": output file exists (use --force to overwrite)");
    }
    if (!options.force && exists_as_file_system_entry(xdmf_file))
      throw InputError(xdmf_file.string() + ": output file exists (use --force to overwrite)");

    const fs::path folder = final_file.has_parent_path() ? final_file.parent_path() : fs::path(".");
    const auto status = fs::status(folder, ec);
    if (!fs::exists(status)) throw InputError(name + ": output folder " + folder.string() + " does not exist");
    if (!fs::is_directory(status)) throw InputError(name + ": " + folder.string() + " is not a folder");
    if (::access(folder.c_str(), W_OK | X_OK) != 0)
      throw InputError(name + ": output folder " + folder.string() + " is not writable");

    if (!options.force && exists_as_file_system_entry(partial_file))
      throw InputError(partial_name() +
                       ": a partial output file exists (another run writing it, or left by a killed "
                       "run); remove it or use --force");
  }

  void check_bodies(const std::vector<OutputBody>& input) const {
    for (std::size_t i = 0; i < input.size(); ++i) {
      const std::string& name = input[i].name;
      if (name.empty() || name == "." || name == ".." || name.find('/') != std::string::npos)
        throw InputError(final_file.string() + ": body name '" + name +
                         "' cannot name an HDF5 group (empty, '.', '..' or containing '/')");
      for (std::size_t j = 0; j < i; ++j)
        if (input[j].name == name) throw InputError(final_file.string() + ": two bodies are named '" + name + "'");
      SOFTDIFF_DEMAND(input[i].rest.cols() > 0, "body '" + name + "' has no nodes");
      const fs::path xdmf_body = xdmf_body_path(final_file, name);
      if (!options.force && exists_as_file_system_entry(xdmf_body))
        throw InputError(xdmf_body.string() + ": output file exists (use --force to overwrite)");
    }
  }

  void create_file() {
    const bool partial_existed = exists_as_file_system_entry(partial_file);
    Handle access(H5Pcreate(H5P_FILE_ACCESS), H5Pclose);
    if (!access.valid() || H5Pset_fclose_degree(access.get(), H5F_CLOSE_STRONG) < 0)
      fail("cannot set up the file access properties");
    const unsigned mode = options.force ? H5F_ACC_TRUNC : H5F_ACC_EXCL;
    file = Handle(H5Fcreate(partial_file.c_str(), mode, H5P_DEFAULT, access.get()), H5Fclose);
    if (!file.valid()) {
      const int error = errno;
      const std::string reason = hdf5_reason();
      std::error_code ec;
      if (!partial_existed) fs::remove(partial_file, ec);
      // A full disk is not a bad input (exit 1); a folder that is not writable is.
      if (error == ENOSPC || error == EDQUOT || reason.find(std::strerror(ENOSPC)) != std::string::npos) {
        last_failure = std::strerror(ENOSPC);
        throw ComputationError(partial_name() + ": cannot create the output file: " + reason);
      }
      throw InputError(partial_name() + ": cannot create the output file: " + reason);
    }
    void* handle = nullptr;
    if (H5Fget_vfd_handle(file.get(), access.get(), &handle) >= 0 && handle != nullptr)
      fd = *static_cast<int*>(handle);
    else
      H5Eclear2(H5E_DEFAULT);
  }

  Handle create_group(const std::string& path) {
    Handle group(H5Gcreate2(file.get(), path.c_str(), H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT), H5Gclose);
    if (!group.valid()) fail("cannot create group " + path);
    return group;
  }

  // Creates a dataset (any missing parent group is created) at `path`.
  Handle create_dataset(const std::string& path, hid_t file_type, hid_t space, hid_t creation, hid_t access) {
    Handle links(H5Pcreate(H5P_LINK_CREATE), H5Pclose);
    if (!links.valid() || H5Pset_create_intermediate_group(links.get(), 1) < 0)
      fail("cannot set up link creation properties");
    Handle dataset(H5Dcreate2(file.get(), path.c_str(), file_type, space, links.get(), creation, access), H5Dclose);
    if (!dataset.valid()) fail("cannot create dataset " + path);
    return dataset;
  }

  // A (rows, cols) dataset written once from row-major memory of type `memory_type`.
  void write_table(const std::string& path, hid_t file_type, hid_t memory_type, hsize_t rows, hsize_t cols,
                   const void* data, const std::string& units) {
    const std::array<hsize_t, 2> shape{rows, cols};
    Handle space(H5Screate_simple(2, shape.data(), nullptr), H5Sclose);
    if (!space.valid()) fail("cannot create the dataspace of " + path);
    Handle dataset = create_dataset(path, file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT);
    set_string_attribute(dataset.get(), "units", units);
    if (rows * cols > 0 && H5Dwrite(dataset.get(), memory_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data) < 0)
      fail("cannot write " + path);
    if (!dataset.reset()) fail("cannot close " + path);
  }

  // An empty (0, d1[, d2]) float64 dataset, unlimited along its first dimension.
  // `direct`: one row per chunk, written straight from the caller's memory.
  // `gzip_level` > 0: shuffled and deflated chunks.
  Appendable create_appendable(const std::string& path, std::vector<hsize_t> row_shape, hsize_t chunk_rows,
                               hsize_t chunk_cols, bool direct, const std::string& units,
                               hid_t file_type = H5T_IEEE_F64LE, hid_t memory_type = H5T_NATIVE_DOUBLE,
                               int gzip_level = 0) {
    Appendable out;
    out.path = path;
    out.memory_type = memory_type;
    out.rank = 1 + static_cast<int>(row_shape.size());
    SOFTDIFF_DEMAND(out.rank <= 3, "appendable datasets have at most 3 dimensions");
    std::array<hsize_t, 3> max_dims{H5S_UNLIMITED, 0, 0};
    std::array<hsize_t, 3> chunk{chunk_rows, 0, 0};
    for (std::size_t i = 0; i < row_shape.size(); ++i) {
      out.dims[i + 1] = max_dims[i + 1] = out.row[i + 1] = row_shape[i];
      chunk[i + 1] = row_shape[i];
    }
    if (out.rank >= 2) chunk[1] = std::min(chunk[1], chunk_cols);

    out.file_space = Handle(H5Screate_simple(out.rank, out.dims.data(), max_dims.data()), H5Sclose);
    out.memory_space = Handle(H5Screate_simple(out.rank, out.row.data(), nullptr), H5Sclose);
    if (!out.file_space.valid() || !out.memory_space.valid()) fail("cannot create the dataspaces of " + path);

    out.direct = direct;
    Handle creation(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
    const Handle access = dataset_access(direct);
    if (!creation.valid() || !access.valid() || H5Pset_chunk(creation.get(), out.rank, chunk.data()) < 0)
      fail("cannot set up the chunks of " + path);
    // A chunk larger than the (empty) chunk cache and no fill value to write:
    // H5Dwrite then writes the caller's buffer to the file without a copy.
    if (direct && H5Pset_fill_time(creation.get(), H5D_FILL_TIME_NEVER) < 0)
      fail("cannot set up the fill value of " + path);
    // Byte shuffle first: the sign and exponent bytes of neighbouring float64 values
    // line up and deflate finds them (x of configs/trunk.yaml: 0.88 of its size with
    // shuffle, 0.95 without; docs/output.md "Compression").
    if (gzip_level > 0 &&
        (H5Pset_shuffle(creation.get()) < 0 || H5Pset_deflate(creation.get(), static_cast<unsigned>(gzip_level)) < 0))
      fail("cannot set up the compression of " + path);
    out.dataset = create_dataset(path, file_type, out.file_space.get(), creation.get(), access.get());
    set_string_attribute(out.dataset.get(), "units", units);
    return out;
  }

  // Frames of (n, 3): one frame per chunk when a frame is large enough, or when
  // compressed (each chunk is then compressed once, when its frame is appended, and
  // never read back or rewritten; reading frame k decompresses one chunk).
  Appendable create_frames(const std::string& path, Eigen::Index nodes, const std::string& units) {
    const std::size_t frame_bytes = static_cast<std::size_t>(nodes) * 3 * sizeof(double);
    const bool compressed = options.gzip_level > 0;
    const hsize_t frames_per_chunk = compressed ? 1 : rows_per_chunk(frame_bytes, kFrameChunkBytes, kMaxChunkRows);
    return create_appendable(path, {static_cast<hsize_t>(nodes), 3}, frames_per_chunk, kMaxChunkNodes,
                             /*direct=*/frames_per_chunk == 1, units, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE,
                             options.gzip_level);
  }

  Appendable create_scalar_series(const std::string& path, const std::string& units) {
    return create_appendable(path, {}, kMaxChunkRows, 0, false, units);
  }

  void open(const WriterOptions& opts, const std::vector<OutputBody>& input) {
    options = opts;
    check_paths();
    check_bodies(input);
    SOFTDIFF_DEMAND(options.flush_every >= 1, "flush_every must be at least 1");
    silence_hdf5_error_printing();
    create_file();
    // Room for the fixed datasets, then for a frame and the close (twice a frame:
    // the chunk cache may hold one unwritten when the next is reserved).
    double fixed_bytes = 64 * 1024 + static_cast<double>(options.scene_yaml.size() + options.command.size());
    double frame_bytes = 0;
    for (const OutputBody& body : input) {
      fixed_bytes += 8.0 * static_cast<double>(body.rest.size() + body.tets.size() + body.surface.size());
      frame_bytes += 24.0 * static_cast<double>(body.rest.cols()) * (options.write_v ? 2 : 1);
    }
    reserve_bytes = std::max(kReserveMinBytes, 2 * frame_bytes + 256 * 1024);
    try {
      if (!reserve_room(fixed_bytes + reserve_bytes)) {
        last_failure = std::strerror(errno);
        throw ComputationError(partial_name() + ": cannot create the output file: " + last_failure + " (it needs " +
                               std::to_string(static_cast<long long>((fixed_bytes + reserve_bytes) / 1024)) +
                               " KiB to start)");
      }
      write_contents(input);
      if (H5Fflush(file.get(), H5F_SCOPE_LOCAL) < 0) fail("cannot flush");
    } catch (...) {
      // The file is removed: empty it first, so that what the close still writes
      // finds room on a full disk.
      if (fd >= 0 && ::ftruncate(fd, 0) != 0) fd = -1;
      close_file();
      std::error_code ec;
      fs::remove(partial_file, ec);
      throw;
    }
  }

  void write_contents(const std::vector<OutputBody>& input) {
    set_int_attribute(file.get(), "softdiff_format", 1);
    set_string_attribute(file.get(), "softdiff_version", SOFTDIFF_VERSION);
    set_string_attribute(file.get(), "command", options.command);
    set_string_attribute(file.get(), "scene_yaml", options.scene_yaml);
    set_string_attribute(file.get(), "created", iso8601_utc_now());
    set_string_attribute(file.get(), "status", "running");

    time = create_scalar_series("/time", "s");
    create_group("/bodies");
    bodies.reserve(input.size());
    for (const OutputBody& body : input) {
      BodyOutput out;
      out.name = body.name;
      out.first_node = total_nodes;
      out.nodes = body.rest.cols();
      out.tets = body.tets.cols();
      out.triangles = body.surface.cols();
      out.nodes_per_tet = body.tets.cols() == 0 ? 4 : static_cast<int>(body.tets.rows());
      SOFTDIFF_DEMAND(out.nodes_per_tet == 4 || out.nodes_per_tet == 10, "OutputBody::tets: 4 or 10 rows");
      const int surface_nodes = out.nodes_per_tet == 10 ? 6 : 3;
      SOFTDIFF_DEMAND(body.surface.cols() == 0 || body.surface.rows() == surface_nodes,
                      "OutputBody::surface: 3 rows, or 6 for a quadratic body");
      total_nodes += out.nodes;
      const std::string group = "/bodies/" + body.name;
      create_group(group);
      // Eigen's column-major (3, n) / (4, m) / (3, k) storage is the row-major
      // (n, 3) / (m, 4) / (k, 3) layout of the datasets: written as is.
      write_table(group + "/rest", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, static_cast<hsize_t>(out.nodes), 3,
                  body.rest.data(), "m");
      write_table(group + "/tets", H5T_STD_I64LE, H5T_NATIVE_INT, static_cast<hsize_t>(out.tets),
                  static_cast<hsize_t>(out.nodes_per_tet), body.tets.data(), "1");
      write_table(group + "/surface", H5T_STD_I64LE, H5T_NATIVE_INT, static_cast<hsize_t>(body.surface.cols()),
                  static_cast<hsize_t>(surface_nodes), body.surface.data(), "1");
      if (out.nodes_per_tet == 10) {
        // XDMF's Tetrahedron_10 lists the edges as VTK does (01 12 20 30 31 32): gmsh's
        // nodes 8 and 9 swapped (xdmf.hpp).
        Eigen::MatrixXi xdmf_tets = body.tets;
        xdmf_tets.row(8).swap(xdmf_tets.row(9));
        write_table(xdmf_tets_path(body.name), H5T_STD_I64LE, H5T_NATIVE_INT, static_cast<hsize_t>(out.tets), 10,
                    xdmf_tets.data(), "1");
      }
      out.rest = Eigen::Map<const VecX>(body.rest.data(), 3 * out.nodes);
      out.displacement.resize(3 * out.nodes);
      out.x = create_frames(group + "/x", out.nodes, "m");
      if (options.write_v) out.v = create_frames(group + "/v", out.nodes, "m/s");
      out.displacement_frames = create_frames(group + "/displacement", out.nodes, "m");
      if (options.write_contact_force) out.contact_force = create_frames(group + "/contact_force", out.nodes, "N");
      bodies.push_back(std::move(out));
    }
    create_group("/solver");
    step_seconds = create_scalar_series("/solver/step_seconds", "s");
    times.reserve(1024);
  }

  // ---- attributes

  // Whether `path` names an object (checked link by link: H5Lexists needs the parents).
  bool path_exists(const std::string& path) const {
    std::size_t at = path.find_first_not_of('/');
    while (at != std::string::npos) {
      const std::size_t end = path.find('/', at);
      if (H5Lexists(file.get(), path.substr(0, end).c_str(), H5P_DEFAULT) <= 0) {
        H5Eclear2(H5E_DEFAULT);
        return false;
      }
      at = end == std::string::npos ? end : path.find_first_not_of('/', end);
    }
    return true;
  }

  Handle open_object(const std::string& object_path) const {
    const std::string path = object_path.empty() ? std::string("/") : object_path;
    SOFTDIFF_DEMAND(path_exists(path), "no object " + path + " in the output file");
    Handle object(H5Oopen(file.get(), path.c_str(), H5P_DEFAULT), H5Oclose);
    if (!object.valid()) fail("cannot open " + path);
    return object;
  }

  void write_attribute(hid_t object, const std::string& name, hid_t file_type, hid_t memory_type,
                       const void* value) const {
    const htri_t exists = H5Aexists(object, name.c_str());
    if (exists < 0 || (exists > 0 && H5Adelete(object, name.c_str()) < 0)) fail("cannot replace attribute " + name);
    Handle space(H5Screate(H5S_SCALAR), H5Sclose);
    if (!space.valid()) fail("cannot create the dataspace of attribute " + name);
    Handle attribute(H5Acreate2(object, name.c_str(), file_type, space.get(), H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (!attribute.valid()) fail("cannot create attribute " + name);
    if (H5Awrite(attribute.get(), memory_type, value) < 0) fail("cannot write attribute " + name);
    if (!attribute.reset()) fail("cannot close attribute " + name);
  }

  // Variable-length UTF-8 string (h5py reads it as str; no size limit).
  void set_string_attribute(hid_t object, const std::string& name, const std::string& value) const {
    Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
    if (!type.valid() || H5Tset_size(type.get(), H5T_VARIABLE) < 0 || H5Tset_cset(type.get(), H5T_CSET_UTF8) < 0)
      fail("cannot create the string type of attribute " + name);
    const char* text = value.c_str();
    write_attribute(object, name, type.get(), type.get(), &text);
  }

  void set_int_attribute(hid_t object, const std::string& name, int value) const {
    write_attribute(object, name, H5T_STD_I32LE, H5T_NATIVE_INT, &value);
  }

  void set_double_attribute(hid_t object, const std::string& name, double value) const {
    write_attribute(object, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, &value);
  }

  void set_int64_attribute(hid_t object, const std::string& name, std::int64_t value) const {
    write_attribute(object, name, H5T_STD_I64LE, H5T_NATIVE_INT64, &value);
  }

  void set_typed_attribute(hid_t object, const Attribute& attribute) const {
    if (const auto* text = std::get_if<std::string>(&attribute.value))
      set_string_attribute(object, attribute.name, *text);
    else if (const auto* real = std::get_if<double>(&attribute.value))
      set_double_attribute(object, attribute.name, *real);
    else
      set_int64_attribute(object, attribute.name, std::get<std::int64_t>(attribute.value));
  }

  // ---- frames

  void append_frame(double t, const VecX& x, const VecX* v, double seconds, const VecX* contact_force) {
    SOFTDIFF_DEMAND(!finished, "append_frame after finish");
    SOFTDIFF_DEMAND(x.size() == 3 * total_nodes,
                    "x has " + std::to_string(x.size()) + " entries, expected " + std::to_string(3 * total_nodes));
    if (options.write_v)
      SOFTDIFF_DEMAND(v != nullptr && v->size() == 3 * total_nodes, "v is missing or has the wrong size");
    if (options.write_contact_force)
      SOFTDIFF_DEMAND(contact_force != nullptr && contact_force->size() == 3 * total_nodes,
                      "contact_force is missing or has the wrong size");
    if (!reserve_room(reserve_bytes)) {
      last_failure = std::strerror(errno);
      throw ComputationError(partial_name() + ": cannot write frame " + std::to_string(frames) + ": " + last_failure +
                             " (no room for it: it was not written, the frames before it are whole)");
    }

    const Appendable* failed = nullptr;
    for (BodyOutput& body : bodies) {
      const auto first = 3 * body.first_node;
      if (!body.x.append(x.data() + first)) { failed = &body.x; break; }
      if (options.write_v && !body.v.append(v->data() + first)) { failed = &body.v; break; }
      body.displacement.noalias() = x.segment(first, 3 * body.nodes) - body.rest;
      if (!body.displacement_frames.append(body.displacement.data())) { failed = &body.displacement_frames; break; }
      if (options.write_contact_force && !body.contact_force.append(contact_force->data() + first)) {
        failed = &body.contact_force;
        break;
      }
    }
    if (failed == nullptr && !step_seconds.append(&seconds)) failed = &step_seconds;
    if (failed == nullptr && !time.append(&t)) failed = &time;
    if (failed != nullptr) {
      const std::string reason = hdf5_reason();
      last_failure = system_part(reason);
      const auto rows = static_cast<hsize_t>(frames);
      for (BodyOutput& body : bodies) {
        body.x.roll_back(file.get(), rows);
        if (options.write_v) body.v.roll_back(file.get(), rows);
        body.displacement_frames.roll_back(file.get(), rows);
        if (options.write_contact_force) body.contact_force.roll_back(file.get(), rows);
      }
      step_seconds.roll_back(file.get(), rows);
      time.roll_back(file.get(), rows);
      H5Eclear2(H5E_DEFAULT);
      throw ComputationError(partial_name() + ": cannot write frame " + std::to_string(frames) + " (" +
                             failed->path + "): " + reason);
    }
    ++frames;
    times.push_back(t);
    if (frames % options.flush_every == 0 && H5Fflush(file.get(), H5F_SCOPE_LOCAL) < 0)
      fail("cannot flush after frame " + std::to_string(frames - 1));
  }

  // ---- generic datasets

  void require_new_path(const std::string& path) const {
    SOFTDIFF_DEMAND(!path.empty() && path.front() == '/', "dataset paths are absolute: '" + path + "'");
    SOFTDIFF_DEMAND(!path_exists(path), path + " already exists in the output file");
  }

  int add_series(const std::string& path, int width, const std::string& units) {
    SOFTDIFF_DEMAND(!finished, "add_series after finish");
    SOFTDIFF_DEMAND(width >= 0, "series width must be >= 0");
    require_new_path(path);
    const std::size_t row_bytes = static_cast<std::size_t>(std::max(width, 1)) * sizeof(double);
    const hsize_t chunk_rows = rows_per_chunk(row_bytes, kSeriesChunkBytes, kMaxChunkRows);
    std::vector<hsize_t> row_shape;
    if (width > 0) row_shape.push_back(static_cast<hsize_t>(width));
    series.push_back(create_appendable(path, row_shape, chunk_rows, static_cast<hsize_t>(width), false, units));
    return static_cast<int>(series.size()) - 1;
  }

  void append_series(int handle, const double* row) {
    SOFTDIFF_DEMAND(!finished, "append_series after finish");
    SOFTDIFF_DEMAND(handle >= 0 && handle < static_cast<int>(series.size()), "unknown series handle");
    SOFTDIFF_DEMAND(row != nullptr, "null row");
    Appendable& target = series[static_cast<std::size_t>(handle)];
    const hsize_t rows = target.dims[0];
    if (!target.append(row)) {
      const std::string reason = hdf5_reason();
      last_failure = system_part(reason);
      target.roll_back(file.get(), rows);
      H5Eclear2(H5E_DEFAULT);
      throw ComputationError(partial_name() + ": cannot write row " + std::to_string(rows) + " of " + target.path +
                             ": " + reason);
    }
  }

  int add_table(const std::string& path, const std::vector<int>& row_shape, Hdf5Writer::Element type,
                const std::string& units) {
    SOFTDIFF_DEMAND(!finished, "add_table after finish");
    SOFTDIFF_DEMAND(row_shape.size() <= 2, "tables have at most 3 dimensions");
    require_new_path(path);
    hid_t file_type = H5T_IEEE_F64LE, memory_type = H5T_NATIVE_DOUBLE;
    std::size_t element_bytes = 8;
    switch (type) {
      case Hdf5Writer::Element::f64: break;
      case Hdf5Writer::Element::i64: file_type = H5T_STD_I64LE; memory_type = H5T_NATIVE_INT64; break;
      case Hdf5Writer::Element::i32: file_type = H5T_STD_I32LE; memory_type = H5T_NATIVE_INT32; element_bytes = 4; break;
      case Hdf5Writer::Element::i8: file_type = H5T_STD_I8LE; memory_type = H5T_NATIVE_INT8; element_bytes = 1; break;
    }
    std::size_t row_bytes = element_bytes;
    std::vector<hsize_t> shape;
    for (int d : row_shape) {
      SOFTDIFF_DEMAND(d > 0, "table row dimensions must be positive");
      shape.push_back(static_cast<hsize_t>(d));
      row_bytes *= static_cast<std::size_t>(d);
    }
    const hsize_t chunk_rows = rows_per_chunk(row_bytes, kSeriesChunkBytes, kMaxChunkRows);
    const hsize_t chunk_cols = shape.empty() ? 1 : shape[0];
    series.push_back(create_appendable(path, shape, chunk_rows, chunk_cols, false, units, file_type, memory_type));
    return static_cast<int>(series.size()) - 1;
  }

  void append_rows(int handle, const void* rows, long count) {
    SOFTDIFF_DEMAND(!finished, "append_rows after finish");
    SOFTDIFF_DEMAND(handle >= 0 && handle < static_cast<int>(series.size()), "unknown table handle");
    SOFTDIFF_DEMAND(count >= 0 && (count == 0 || rows != nullptr), "bad rows");
    if (count == 0) return;
    Appendable& target = series[static_cast<std::size_t>(handle)];
    const hsize_t before = target.dims[0];
    if (!target.append_rows(rows, static_cast<hsize_t>(count))) {
      const std::string reason = hdf5_reason();
      last_failure = system_part(reason);
      target.roll_back(file.get(), before);
      H5Eclear2(H5E_DEFAULT);
      throw ComputationError(partial_name() + ": cannot append " + std::to_string(count) + " rows to " +
                             target.path + ": " + reason);
    }
  }

  void write_strings(const std::string& path, const std::vector<std::string>& values, const std::string& units) {
    SOFTDIFF_DEMAND(!finished, "write_strings after finish");
    require_new_path(path);
    Handle type(H5Tcopy(H5T_C_S1), H5Tclose);
    if (!type.valid() || H5Tset_size(type.get(), H5T_VARIABLE) < 0 || H5Tset_cset(type.get(), H5T_CSET_UTF8) < 0)
      fail("cannot create the string type of " + path);
    const std::array<hsize_t, 1> shape{values.size()};
    Handle space(H5Screate_simple(1, shape.data(), nullptr), H5Sclose);
    if (!space.valid()) fail("cannot create the dataspace of " + path);
    Handle dataset = create_dataset(path, type.get(), space.get(), H5P_DEFAULT, H5P_DEFAULT);
    set_string_attribute(dataset.get(), "units", units);
    std::vector<const char*> pointers;
    for (const auto& v : values) pointers.push_back(v.c_str());
    if (!values.empty() && H5Dwrite(dataset.get(), type.get(), H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) < 0)
      fail("cannot write " + path);
    if (!dataset.reset()) fail("cannot close " + path);
  }

  void write_matrix(const std::string& path, const MatX& value, const std::string& units,
                    const std::vector<Attribute>& attributes) {
    SOFTDIFF_DEMAND(!finished, "write_matrix after finish");
    require_new_path(path);
    // Eigen stores MatX column-major; the dataset is row-major.
    const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> rows = value;
    write_table(path, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, static_cast<hsize_t>(rows.rows()),
                static_cast<hsize_t>(rows.cols()), rows.data(), units);
    if (!attributes.empty()) {
      Handle dataset = open_object(path);
      for (const Attribute& attribute : attributes) set_typed_attribute(dataset.get(), attribute);
    }
  }

  // ---- the XDMF files' per-frame views

  // The node fields of every frame, as named in /bodies/<b>/ and in the XDMF.
  std::vector<std::string> node_fields() const {
    std::vector<std::string> fields{"x"};
    if (options.write_v) fields.push_back("v");
    fields.push_back("displacement");
    if (options.write_contact_force) fields.push_back("contact_force");
    return fields;
  }

  // /xdmf/<body>/<field>/<k>: frame k of /bodies/<body>/<field> as an (n, 3) virtual
  // dataset (a mapping to the slab of the source, no copy of the values), so that
  // the XDMF names each frame's data as a plain HDF dataset (xdmf.hpp). About 0.5 kB
  // per view.
  void write_frame_views() {
    if (frames == 0) return;
    Handle links(H5Pcreate(H5P_LINK_CREATE), H5Pclose);
    if (!links.valid() || H5Pset_create_intermediate_group(links.get(), 1) < 0)
      fail("cannot set up link creation properties");
    for (const BodyOutput& body : bodies) {
      const std::array<hsize_t, 2> shape{static_cast<hsize_t>(body.nodes), 3};
      const std::array<hsize_t, 3> source_shape{static_cast<hsize_t>(frames), shape[0], 3};
      Handle view_space(H5Screate_simple(2, shape.data(), nullptr), H5Sclose);
      Handle source_space(H5Screate_simple(3, source_shape.data(), nullptr), H5Sclose);
      if (!view_space.valid() || !source_space.valid()) fail("cannot create the dataspaces of the frame views");
      for (const std::string& field : node_fields()) {
        const std::string source = "/bodies/" + body.name + "/" + field;
        // The source name is a printf-like pattern for HDF5: '%' is written '%%'.
        std::string pattern;
        for (const char c : source) pattern += c == '%' ? std::string("%%") : std::string(1, c);
        const std::string units = field == "v" ? "m/s" : field == "contact_force" ? "N" : "m";
        for (long k = 0; k < frames; ++k) {
          const std::string path = frame_view_path(body.name, field, k);
          const std::array<hsize_t, 3> start{static_cast<hsize_t>(k), 0, 0}, count{1, shape[0], 3};
          Handle creation(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
          if (!creation.valid() ||
              H5Sselect_hyperslab(source_space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr) < 0 ||
              H5Pset_virtual(creation.get(), view_space.get(), ".", pattern.c_str(), source_space.get()) < 0)
            fail("cannot set up the view " + path);
          Handle view(H5Dcreate2(file.get(), path.c_str(), H5T_IEEE_F64LE, view_space.get(), links.get(),
                                 creation.get(), H5P_DEFAULT),
                      H5Dclose);
          if (!view.valid()) fail("cannot create the view " + path);
          set_string_attribute(view.get(), "units", units);
        }
      }
    }
  }

  // out.xmf (every body) and out.<body>.xmf (one each), xdmf.hpp, beside the HDF5
  // file where the frames went: the output's name, or a side file (out.interrupted.h5
  // -> out.interrupted.xmf, out.interrupted.<body>.xmf).
  void write_xdmf_files(const fs::path& h5_file) const {
    std::vector<XdmfBody> described;
    described.reserve(bodies.size());
    for (const BodyOutput& body : bodies)
      described.push_back({body.name, static_cast<long>(body.nodes), static_cast<long>(body.tets), body.nodes_per_tet,
                           static_cast<long>(body.triangles)});
    const std::string h5_name = h5_file.filename().string();
    const std::vector<std::string> fields = node_fields();
    for (const XdmfBody& body : described)
      write_text_file_atomically(xdmf_body_path(h5_file, body.name), xdmf_text(h5_name, {body}, times, fields));
    fs::path whole = h5_file;
    write_text_file_atomically(whole.replace_extension(".xmf"), xdmf_text(h5_name, described, times, fields));
  }

  // ---- finishing

  // Closes every identifier; false if HDF5 reported an error (e.g. a failed flush).
  bool close_everything() {
    bool ok = true;
    for (Appendable& s : series) ok = s.close() && ok;
    for (BodyOutput& body : bodies) {
      ok = body.x.close() && ok;
      ok = body.v.close() && ok;
      ok = body.displacement_frames.close() && ok;
      ok = body.contact_force.close() && ok;
    }
    ok = step_seconds.close() && ok;
    ok = time.close() && ok;
    return file.reset() && ok;
  }

  // Moves <file>.partial to `target`: replacing a file there when `replace`, else
  // never (link() fails on an existing name, atomically). False, with `error`, if
  // it could not (the frames then stay in <file>.partial).
  bool move_to(const fs::path& target, bool replace, std::string& error) {
    std::error_code ec;
    if (!replace) {
      if (::link(partial_file.c_str(), target.c_str()) == 0) {
        fs::remove(partial_file, ec);
        return true;
      }
      // File systems without hard links: check, then rename.
      if (errno == EEXIST || exists_as_file_system_entry(target)) {
        error = target.string() + " exists";
        return false;
      }
    }
    fs::rename(partial_file, target, ec);
    if (ec) error = partial_name() + ": cannot rename to " + target.string() + ": " + ec.message();
    return !ec;
  }

  void finish(const std::string& status) {
    if (finished) return;
    finished = true;
    written_file = partial_file;
    std::string problem;  // why the file is not a clean, closed file with its status
    try {
      write_frame_views();
      set_string_attribute(file.get(), "status", status);
    } catch (const std::exception& e) {
      problem = std::string(e.what()) + " (the file's status still says running)";
    }
    if (!close_file()) {
      problem += (problem.empty() ? "" : "; ") + partial_name() + ": cannot close: " + hdf5_reason() +
                 " (frames after the last flush may be lost)";
    }
    const bool complete = status == "complete" && problem.empty();

    fs::path target = final_file;
    std::string error;
    if (complete) {
      if (!move_to(final_file, options.force, error)) {
        if (!options.force && exists_as_file_system_entry(final_file))
          throw InputError(final_file.string() + ": output file appeared during the run; the output is in " +
                           partial_name());
        throw ComputationError(error);
      }
    } else {
      // An unfinished run takes the output's name only if no file has it; otherwise
      // (--force over an old file, or a file that appeared meanwhile) a side file.
      const std::string kind = problem.empty() ? status.substr(0, status.find(':')) : std::string("failed");
      bool placed = !problem.empty() || exists_as_file_system_entry(final_file) ? false : move_to(final_file, false, error);
      if (!placed) {
        target = side_file_name(final_file, kind);
        error.clear();
        placed = move_to(target, options.force, error);
      }
      if (!placed) {
        problem += (problem.empty() ? "" : "; ") + error;
        target = partial_file;
      }
    }
    written_file = target;
    if (target == partial_file || !problem.empty()) {
      throw ComputationError(problem + " (the frames written so far are in " + written_file.string() + ")");
    }

    write_xdmf_files(target);
  }
};

// ---------------------------------------------------------------------------

Hdf5Writer::Hdf5Writer(const WriterOptions& options, const std::vector<OutputBody>& bodies)
    : impl_(std::make_unique<Impl>()) {
  impl_->open(options, bodies);
}

Hdf5Writer::~Hdf5Writer() {
  if (!impl_) return;
  try {
    // Reached without finish() only when the run ended with an exception.
    impl_->finish("failed: the run ended with an error");
  } catch (...) {
    // Never throws: the frames flushed so far stay in <file>.partial.
  }
}

void Hdf5Writer::append_frame(double time, const VecX& x, const VecX* v, double step_seconds,
                              const VecX* contact_force) {
  impl_->append_frame(time, x, v, step_seconds, contact_force);
}

int Hdf5Writer::add_series(const std::string& path, int width, const std::string& units) {
  return impl_->add_series(path, width, units);
}

void Hdf5Writer::append_series(int handle, const double* row) { impl_->append_series(handle, row); }

int Hdf5Writer::add_table(const std::string& path, const std::vector<int>& row_shape, Element type,
                          const std::string& units) {
  return impl_->add_table(path, row_shape, type, units);
}

void Hdf5Writer::append_rows(int handle, const void* rows, long count) { impl_->append_rows(handle, rows, count); }

void Hdf5Writer::write_strings(const std::string& path, const std::vector<std::string>& values,
                               const std::string& units) {
  impl_->write_strings(path, values, units);
}

void Hdf5Writer::write_matrix(const std::string& path, const MatX& value, const std::string& units,
                              const std::vector<Attribute>& attributes) {
  impl_->write_matrix(path, value, units, attributes);
}

void Hdf5Writer::set_attribute(const std::string& object_path, const std::string& name, const std::string& value) {
  SOFTDIFF_DEMAND(!impl_->finished, "set_attribute after finish");
  const Handle object = impl_->open_object(object_path);
  impl_->set_string_attribute(object.get(), name, value);
}

void Hdf5Writer::set_attribute(const std::string& object_path, const std::string& name, const char* value) {
  set_attribute(object_path, name, std::string(value));
}

void Hdf5Writer::set_attribute(const std::string& object_path, const std::string& name, double value) {
  SOFTDIFF_DEMAND(!impl_->finished, "set_attribute after finish");
  const Handle object = impl_->open_object(object_path);
  impl_->set_double_attribute(object.get(), name, value);
}

void Hdf5Writer::set_attribute(const std::string& object_path, const std::string& name, std::int64_t value) {
  SOFTDIFF_DEMAND(!impl_->finished, "set_attribute after finish");
  const Handle object = impl_->open_object(object_path);
  impl_->set_int64_attribute(object.get(), name, value);
}

void Hdf5Writer::set_attribute(const std::string& object_path, const std::string& name, int value) {
  set_attribute(object_path, name, static_cast<std::int64_t>(value));
}

void Hdf5Writer::finish(const std::string& status) { impl_->finish(status); }

long Hdf5Writer::frames_written() const { return impl_->frames; }

const std::filesystem::path& Hdf5Writer::final_path() const {
  return impl_->finished ? impl_->written_file : impl_->final_file;
}

const std::string& Hdf5Writer::failure() const { return impl_->last_failure; }

std::filesystem::path side_file_name(const std::filesystem::path& file, const std::string& kind) {
  fs::path side = file;
  side.replace_filename(file.stem().string() + "." + kind + file.extension().string());
  return side;
}

std::vector<std::filesystem::path> output_file_names(const std::filesystem::path& file,
                                                     const std::vector<std::string>& body_names) {
  std::vector<fs::path> names;
  const auto add = [&](const fs::path& h5) {
    names.push_back(h5);
    fs::path xdmf = h5;
    names.push_back(xdmf.replace_extension(".xmf"));
    for (const std::string& body : body_names) names.push_back(xdmf_body_path(h5, body));
  };
  add(file);
  fs::path partial = file;
  names.push_back(partial += ".partial");
  for (const char* kind : {"interrupted", "diverged", "failed"}) add(side_file_name(file, kind));
  return names;
}

OutputEstimate estimate_output(const std::vector<OutputBody>& bodies, bool write_v, bool write_contact_force,
                               long frames, double series_per_frame, const std::string& h5_name) {
  OutputEstimate e;
  double fixed = 64 * 1024;  // superblock, groups, attributes (measured: about 20 KiB)
  e.frame_bytes = 16 + series_per_frame;  // /time, /solver/step_seconds
  // Per node and frame: x, displacement, and v and the contact force when written.
  std::vector<std::string> fields{"x", "displacement"};
  if (write_v) fields.push_back("v");
  if (write_contact_force) fields.push_back("contact_force");
  const auto node_fields = static_cast<double>(fields.size());
  std::vector<XdmfBody> described;
  for (const OutputBody& b : bodies) {
    fixed += 8.0 * static_cast<double>(b.rest.size() + b.tets.size() + b.surface.size());
    if (b.tets.rows() == 10) fixed += 8.0 * static_cast<double>(b.tets.size());  // /xdmf/<b>/tets
    e.frame_bytes += 24.0 * static_cast<double>(b.rest.cols()) * node_fields;
    e.frame_bytes += 512.0 * node_fields;  // the frame's views /xdmf/<b>/<field>/<k> (about 0.5 kB each)
    described.push_back({b.name, static_cast<long>(b.rest.cols()), static_cast<long>(b.tets.cols()),
                         b.tets.rows() == 10 ? 10 : 4, static_cast<long>(b.surface.cols())});
  }
  const auto frames_d = static_cast<double>(std::max<long>(frames, 1));
  e.hdf5_bytes = fixed + e.frame_bytes * frames_d;
  // The XDMF files (out.xmf, and out.<body>.xmf per body) grow by the same text per
  // frame: measured on one and two frames (the second time with 17 digits), plus the
  // longer frame numbers of a long run (in each view's name).
  const auto per_frame = [&](const std::vector<XdmfBody>& these) {
    const double one = static_cast<double>(xdmf_text(h5_name, these, {0.0}, fields).size());
    const double two = static_cast<double>(xdmf_text(h5_name, these, {0.0, 0.1234567890123456}, fields).size());
    const double digits = static_cast<double>(std::to_string(std::max<long>(frames, 1)).size()) - 1;
    const double views = static_cast<double>(these.size()) * node_fields;
    return one + (two - one + digits * views) * (frames_d - 1);
  };
  e.xdmf_bytes = per_frame(described);
  for (const XdmfBody& b : described) e.xdmf_bytes += per_frame({b});
  return e;
}

bool hdf5_close_failed() { return g_close_failed; }

std::string hdf5_version() {
  unsigned major = 0, minor = 0, release = 0;
  H5get_libversion(&major, &minor, &release);
  return std::to_string(major) + "." + std::to_string(minor) + "." + std::to_string(release);
}

}  // namespace softdiff::io
