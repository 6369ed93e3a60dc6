#include "storetrack/geometry/symmetric_eigen.hpp"

#include <Eigen/Eigenvalues>

namespace storetrack::geometry {

SymmetricEigen symmetric_eigen(const Eigen::MatrixXd& symmetric, bool with_vectors) {
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(
      symmetric, with_vectors ? Eigen::ComputeEigenvectors : Eigen::EigenvaluesOnly);
  SymmetricEigen out;
  out.values = solver.eigenvalues();
  if (with_vectors) out.vectors = solver.eigenvectors();
  return out;
}

}  // namespace storetrack::geometry
