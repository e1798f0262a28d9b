#pragma once
// Basic types shared by every stage. Public headers expose Eigen and std types only.
#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <array>
#include <cstdint>
#include <vector>

namespace softdiff {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Vec9 = Eigen::Matrix<double, 9, 1>;
using Mat9 = Eigen::Matrix<double, 9, 9>;
using Vec12 = Eigen::Matrix<double, 12, 1>;
using Mat12 = Eigen::Matrix<double, 12, 12>;
using Vec30 = Eigen::Matrix<double, 30, 1>;   // a 10-node tetrahedron's dofs
using Mat30 = Eigen::Matrix<double, 30, 30>;
using VecX = Eigen::VectorXd;
using MatX = Eigen::MatrixXd;
using Mat3X = Eigen::Matrix<double, 3, Eigen::Dynamic>;
using Tets = Eigen::Matrix<int, 4, Eigen::Dynamic>;       // one column per tetrahedron
using Triangles = Eigen::Matrix<int, 3, Eigen::Dynamic>;  // one column per triangle

// Symmetric sparse matrices are stored as their upper triangle (row <= col) in
// compressed-column form; this is what CHOLMOD (stype = 1) and Eigen's
// SimplicialLDLT<..., Upper> consume without a copy.
using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

}  // namespace softdiff
