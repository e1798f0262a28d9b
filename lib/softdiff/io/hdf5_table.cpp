// A table of named columns as an HDF5 file: see hdf5_table.hpp.
#include <softdiff/io/hdf5_table.hpp>

#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>

#include <hdf5.h>

namespace softdiff::io {

namespace {

// A variable-length UTF-8 string type, as the output's strings (hdf5_writer.cpp): h5py
// reads it as str. The caller closes it.
hid_t utf8_string_type() {
  const hid_t type = H5Tcopy(H5T_C_S1);
  H5Tset_size(type, H5T_VARIABLE);
  H5Tset_cset(type, H5T_CSET_UTF8);
  return type;
}

// A scalar string attribute; false if HDF5 failed.
bool write_string_attribute(hid_t object, const char* name, const std::string& value) {
  const hid_t type = utf8_string_type();
  const hid_t space = H5Screate(H5S_SCALAR);
  const hid_t a = H5Acreate2(object, name, type, space, H5P_DEFAULT, H5P_DEFAULT);
  const char* text = value.c_str();
  const bool ok = a >= 0 && H5Awrite(a, type, &text) >= 0;
  if (a >= 0) H5Aclose(a);
  H5Sclose(space);
  H5Tclose(type);
  return ok;
}

}  // namespace

void write_hdf5_table(const std::filesystem::path& file, const std::vector<TableColumn>& columns) {
  const hsize_t n = columns.empty() ? 0
                                    : std::visit([](const auto& v) { return static_cast<hsize_t>(v.size()); },
                                                 columns.front().values);
  for (const TableColumn& c : columns) {
    const auto rows = std::visit([](const auto& v) { return static_cast<hsize_t>(v.size()); }, c.values);
    SOFTDIFF_DEMAND(rows == n, "column " + c.name + " has " + std::to_string(rows) + " rows, expected " +
                                   std::to_string(n));
  }
  const std::filesystem::path partial = file.string() + ".partial";
  const hid_t f = H5Fcreate(partial.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  if (f < 0) throw ComputationError(file.string() + ": cannot create the HDF5 table");
  std::string names;
  for (const TableColumn& c : columns) names += (names.empty() ? "" : ",") + c.name;
  bool ok = write_string_attribute(f, "columns", names);
  const hid_t space = H5Screate_simple(1, &n, nullptr);
  // Column names are dataset names at the root: no intermediate groups for a '/'.
  const hid_t links = H5Pcreate(H5P_LINK_CREATE);
  H5Pset_create_intermediate_group(links, 0);
  for (const TableColumn& c : columns) {
    hid_t d = -1;
    if (const auto* values = std::get_if<std::vector<double>>(&c.values)) {
      d = H5Dcreate2(f, c.name.c_str(), H5T_IEEE_F64LE, space, links, H5P_DEFAULT, H5P_DEFAULT);
      ok = ok && d >= 0 &&
           (n == 0 || H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, values->data()) >= 0);
    } else {
      const hid_t type = utf8_string_type();
      std::vector<const char*> pointers;
      for (const std::string& s : std::get<std::vector<std::string>>(c.values)) pointers.push_back(s.c_str());
      d = H5Dcreate2(f, c.name.c_str(), type, space, links, H5P_DEFAULT, H5P_DEFAULT);
      ok = ok && d >= 0 && (n == 0 || H5Dwrite(d, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, pointers.data()) >= 0);
      H5Tclose(type);
    }
    if (d >= 0) {
      ok = write_string_attribute(d, "units", c.units) && ok;
      H5Dclose(d);
    }
  }
  H5Pclose(links);
  H5Sclose(space);
  ok = H5Fclose(f) >= 0 && ok;
  std::error_code ec;
  if (ok) std::filesystem::rename(partial, file, ec);
  if (!ok || ec) {
    std::filesystem::remove(partial, ec);
    throw ComputationError(file.string() + ": writing the HDF5 table failed");
  }
}

}  // namespace softdiff::io
