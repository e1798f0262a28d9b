#pragma once
// A table of named columns as an HDF5 file: collect's TABLE.h5 (docs/cli.md "collect").
// Only std types here (STYLE.md section 1): HDF5 stays in hdf5_table.cpp.
#include <filesystem>
#include <string>
#include <variant>
#include <vector>

namespace softdiff::io {

// One column: float64 values (NaN for an empty cell) or text.
struct TableColumn {
  std::string name;   // the dataset's name at the root (no '/')
  std::string units;  // its `units` attribute (docs/output.md's spelling: "m", "s", "1", ...)
  std::variant<std::vector<double>, std::vector<std::string>> values;
};

// Writes `file` with one 1-D dataset per column at the root, in the given order:
// float64 (little-endian IEEE) or variable-length UTF-8 strings, each with the string
// attribute `units`; the root's string attribute `columns` lists the names joined by
// ','. Every column must have the same number of rows (SOFTDIFF_DEMAND). The file is
// written as <file>.partial and renamed to `file` (replacing it) only when complete;
// on failure the partial file is removed and ComputationError names `file`.
void write_hdf5_table(const std::filesystem::path& file, const std::vector<TableColumn>& columns);

}  // namespace softdiff::io
