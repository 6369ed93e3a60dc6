// Eigen-decomposition of a symmetric matrix of any size, compiled once.
//
// Eigen's SelfAdjointEigenSolver is a large template: instantiated at dynamic size it was most of
// the compile time of each source that used it (common/camera/src/calibration_file.cpp: 47 s of
// CPU with GCC -O2 for aarch64, 50 s with clang ASan), in every build tree and fuzzer. Sources
// that check or factor a covariance of run-time size call this instead. Fixed-size 3x3 uses on
// the per-exposure path keep Eigen's own (unrolled, no allocation).
#pragma once

#include <Eigen/Core>

namespace storetrack::geometry {

struct SymmetricEigen {
  Eigen::VectorXd values;   ///< ascending
  Eigen::MatrixXd vectors;  ///< column i belongs to values(i); empty when only values were asked
};

/// Decomposes `symmetric` (only its lower triangle is read, as Eigen's solver does).
SymmetricEigen symmetric_eigen(const Eigen::MatrixXd& symmetric, bool with_vectors = true);

}  // namespace storetrack::geometry
