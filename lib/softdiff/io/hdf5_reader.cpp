// Reading HDF5 files back: see hdf5_reader.hpp.
//
// Every HDF5 call runs between H5E_BEGIN_TRY and H5E_END_TRY: a missing object is an
// expected answer here, so HDF5 must not print its error stack for it.
#include <softdiff/io/hdf5_reader.hpp>

#include <hdf5.h>

#include <algorithm>
#include <type_traits>

namespace softdiff::io {

static_assert(std::is_same_v<hid_t, std::int64_t>, "Hdf5Reader stores a hid_t as std::int64_t (HDF5 >= 1.10)");

namespace {

herr_t collect_name(hid_t, const char* name, const H5L_info_t*, void* data) {
  static_cast<std::vector<std::string>*>(data)->push_back(name);
  return 0;
}

herr_t collect_numeric_attribute(hid_t object, const char* name, const H5A_info_t*, void* data) {
  const hid_t a = H5Aopen(object, name, H5P_DEFAULT);
  if (a < 0) return 0;
  const hid_t type = H5Aget_type(a);
  const H5T_class_t c = H5Tget_class(type);
  double v = 0;
  if ((c == H5T_INTEGER || c == H5T_FLOAT) && H5Aread(a, H5T_NATIVE_DOUBLE, &v) >= 0)
    static_cast<std::vector<std::pair<std::string, double>>*>(data)->emplace_back(name, v);
  H5Tclose(type);
  H5Aclose(a);
  return 0;
}

}  // namespace

std::optional<std::string> read_status(const std::filesystem::path& file) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(file, ec)) return std::nullopt;
  std::optional<std::string> value;
  H5E_BEGIN_TRY {
    const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
    if (f >= 0) {
      const hid_t a = H5Aopen(f, "status", H5P_DEFAULT);
      if (a >= 0) {
        const hid_t type = H5Aget_type(a);
        const hid_t memory = H5Tcopy(H5T_C_S1);
        H5Tset_size(memory, H5T_VARIABLE);
        H5Tset_cset(memory, H5Tget_cset(type));
        char* text = nullptr;
        if (H5Tis_variable_str(type) > 0 && H5Aread(a, memory, &text) >= 0 && text != nullptr) value = text;
        if (text != nullptr) H5free_memory(text);
        H5Tclose(memory);
        H5Tclose(type);
        H5Aclose(a);
      }
      H5Fclose(f);
    }
  }
  H5E_END_TRY;
  return value;
}

Hdf5Reader::Hdf5Reader(const std::filesystem::path& file) {
  H5E_BEGIN_TRY { file_ = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT); }
  H5E_END_TRY;
}

Hdf5Reader::~Hdf5Reader() {
  if (file_ >= 0) H5Fclose(file_);
}

bool Hdf5Reader::ok() const { return file_ >= 0; }

bool Hdf5Reader::exists(const std::string& path) const {
  if (file_ < 0) return false;
  htri_t e = -1;
  H5E_BEGIN_TRY { e = H5Lexists(file_, path.c_str(), H5P_DEFAULT); }
  H5E_END_TRY;
  return e > 0;
}

std::vector<double> Hdf5Reader::read(const std::string& path, std::vector<std::size_t>* shape) const {
  std::vector<double> v;
  if (!exists(path)) return v;
  H5E_BEGIN_TRY {
    const hid_t d = H5Dopen2(file_, path.c_str(), H5P_DEFAULT);
    if (d >= 0) {
      const hid_t s = H5Dget_space(d);
      std::vector<hsize_t> dims(static_cast<std::size_t>(std::max(0, H5Sget_simple_extent_ndims(s))));
      H5Sget_simple_extent_dims(s, dims.data(), nullptr);
      std::size_t n = 1;
      for (const hsize_t k : dims) n *= static_cast<std::size_t>(k);
      v.resize(n);
      const bool read = n == 0 || H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()) >= 0;
      if (!read) v.clear();
      if (read && shape != nullptr) shape->assign(dims.begin(), dims.end());
      H5Sclose(s);
      H5Dclose(d);
    }
  }
  H5E_END_TRY;
  return v;
}

std::vector<std::string> Hdf5Reader::members(const std::string& group) const {
  std::vector<std::string> names;
  if (!exists(group) && group != "/") return names;
  H5E_BEGIN_TRY {
    const hid_t g = H5Gopen2(file_, group.c_str(), H5P_DEFAULT);
    if (g >= 0) {
      H5Literate(g, H5_INDEX_CRT_ORDER, H5_ITER_INC, nullptr, collect_name, &names);
      if (names.empty()) H5Literate(g, H5_INDEX_NAME, H5_ITER_INC, nullptr, collect_name, &names);
      H5Gclose(g);
    }
  }
  H5E_END_TRY;
  return names;
}

std::vector<std::pair<std::string, double>> Hdf5Reader::numeric_attributes(const std::string& object) const {
  std::vector<std::pair<std::string, double>> out;
  if (!exists(object) && object != "/") return out;
  H5E_BEGIN_TRY {
    const hid_t o = H5Oopen(file_, object.c_str(), H5P_DEFAULT);
    if (o >= 0) {
      if (H5Aiterate2(o, H5_INDEX_CRT_ORDER, H5_ITER_INC, nullptr, collect_numeric_attribute, &out) < 0 ||
          out.empty()) {
        out.clear();
        H5Aiterate2(o, H5_INDEX_NAME, H5_ITER_INC, nullptr, collect_numeric_attribute, &out);
      }
      H5Oclose(o);
    }
  }
  H5E_END_TRY;
  return out;
}

}  // namespace softdiff::io
