#pragma once
// Reading back the CLI's HDF5 output in tests: dataset shapes and values, attributes.
#include <Eigen/Core>
#include <gtest/gtest.h>
#include <hdf5.h>

#include <limits>
#include <string>
#include <vector>

namespace softdiff::test {

inline std::vector<hsize_t> h5_shape(hid_t f, const std::string& path) {
  std::vector<hsize_t> dims;
  const hid_t d = H5Dopen2(f, path.c_str(), H5P_DEFAULT);
  if (d < 0) return dims;
  const hid_t s = H5Dget_space(d);
  dims.resize(static_cast<std::size_t>(H5Sget_simple_extent_ndims(s)));
  H5Sget_simple_extent_dims(s, dims.data(), nullptr);
  H5Sclose(s);
  H5Dclose(d);
  return dims;
}

inline std::vector<double> h5_read(hid_t f, const std::string& path) {
  std::size_t n = 1;
  for (hsize_t d : h5_shape(f, path)) n *= d;
  std::vector<double> v(n);
  const hid_t d = H5Dopen2(f, path.c_str(), H5P_DEFAULT);
  EXPECT_GE(H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, v.data()), 0) << path;
  H5Dclose(d);
  return v;
}

inline std::string h5_string_attribute(hid_t f, const std::string& object, const std::string& name) {
  const hid_t o = H5Oopen(f, object.c_str(), H5P_DEFAULT);
  const hid_t a = H5Aopen(o, name.c_str(), H5P_DEFAULT);
  std::string value;
  if (a >= 0) {
    const hid_t type = H5Aget_type(a);
    char* s = nullptr;
    const hid_t mem = H5Tcopy(H5T_C_S1);
    H5Tset_size(mem, H5T_VARIABLE);
    H5Tset_cset(mem, H5Tget_cset(type));
    if (H5Aread(a, mem, &s) >= 0 && s) value = s;
    H5free_memory(s);
    H5Tclose(mem);
    H5Tclose(type);
    H5Aclose(a);
  }
  H5Oclose(o);
  return value;
}

// A numeric attribute (NaN if absent).
inline double h5_number_attribute(hid_t f, const std::string& object, const std::string& name) {
  const hid_t o = H5Oopen(f, object.c_str(), H5P_DEFAULT);
  double v = std::numeric_limits<double>::quiet_NaN();
  if (o >= 0) {
    const hid_t a = H5Aopen(o, name.c_str(), H5P_DEFAULT);
    if (a >= 0) {
      H5Aread(a, H5T_NATIVE_DOUBLE, &v);
      H5Aclose(a);
    }
    H5Oclose(o);
  }
  return v;
}

// The last frame of a (T, n, 3) dataset such as /bodies/<b>/x, node-major (3n).
inline Eigen::VectorXd h5_final_frame(const std::string& file, const std::string& path) {
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  const auto dims = h5_shape(f, path);
  const std::vector<double> x = h5_read(f, path);
  H5Fclose(f);
  const std::size_t per_frame = static_cast<std::size_t>(dims[1] * dims[2]);
  return Eigen::Map<const Eigen::VectorXd>(x.data() + x.size() - per_frame, static_cast<Eigen::Index>(per_frame));
}

}  // namespace softdiff::test
