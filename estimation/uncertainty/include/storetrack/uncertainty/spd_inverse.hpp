// Inverse of a small fixed-size symmetric positive definite matrix (normal matrices, mark
// covariances): 2x2 and 3x3 in closed form, larger through the Cholesky factor H = L L^T:
// H^-1 = L^-T L^-1, with L^-1 by forward substitution in fixed-size loops. Eigen's
// llt.solve(Identity) routes a matrix right-hand side through the blocked triangular solver, whose
// set-up dominates for 3x3 and 6x6 matrices on the per-exposure path (docs/performance.md, "Host
// processing"); its factorisation too, so fixed sizes use cholesky_lower below, as do the
// Gauss-Newton steps (solve_spd).
#pragma once

#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/LU>

namespace storetrack::uncertainty {

/// Lower Cholesky factor L (H = L L^T, from H's lower triangle) of a fixed-size symmetric
/// positive definite matrix, in loops of constant bounds (unrolled by the compiler: Eigen's LLT
/// runs its run-time-sized blocked algorithm even for 6x6). False when a pivot is not positive
/// (NaN included); L is then unspecified.
template <int N>
bool cholesky_lower(const Eigen::Matrix<double, N, N>& H, Eigen::Matrix<double, N, N>& L) {
  static_assert(N > 0, "cholesky_lower: fixed size only");
  L.setZero();
  for (int j = 0; j < N; ++j) {
    double d = H(j, j);
    for (int k = 0; k < j; ++k)
      d -= L(j, k) * L(j, k);
    if (!(d > 0)) return false;
    L(j, j) = std::sqrt(d);
    const double inv = 1.0 / L(j, j);
    for (int i = j + 1; i < N; ++i) {
      double s = H(i, j);
      for (int k = 0; k < j; ++k)
        s -= L(i, k) * L(j, k);
      L(i, j) = s * inv;
    }
  }
  return true;
}

/// x = H^-1 b for a fixed-size symmetric positive definite H (Gauss-Newton steps), through its
/// Cholesky factor. False (x untouched) when H is not numerically positive definite or x is not
/// finite.
template <int N>
bool solve_spd(const Eigen::Matrix<double, N, N>& H, const Eigen::Matrix<double, N, 1>& b,
               Eigen::Matrix<double, N, 1>& x) {
  Eigen::Matrix<double, N, N> L;
  if (!cholesky_lower<N>(H, L)) return false;
  Eigen::Matrix<double, N, 1> y;
  for (int i = 0; i < N; ++i) {  // L y = b
    double s = b(i);
    for (int k = 0; k < i; ++k)
      s -= L(i, k) * y(k);
    y(i) = s / L(i, i);
  }
  for (int i = N - 1; i >= 0; --i) {  // L^T x = y
    double s = y(i);
    for (int k = i + 1; k < N; ++k)
      s -= L(k, i) * y(k);
    y(i) = s / L(i, i);
  }
  if (!y.allFinite()) return false;
  x = y;
  return true;
}

/// Returns false (out untouched) when H is not numerically positive definite. N may be
/// Eigen::Dynamic (joint calibration normal matrices, whose size depends on the rig).
template <int N>
bool inverse_spd(const Eigen::Matrix<double, N, N>& H, Eigen::Matrix<double, N, N>& out) {
  if constexpr (N == 2) {
    // 2x2 (pixel covariances): positive definite iff H00 > 0 and det > 0; inverse in closed form.
    const double det = H(0, 0) * H(1, 1) - H(0, 1) * H(1, 0);
    if (!(H(0, 0) > 0) || !(det > 0)) return false;
    Eigen::Matrix<double, 2, 2> inv;
    inv << H(1, 1) / det, -H(0, 1) / det, -H(1, 0) / det, H(0, 0) / det;
    if (!inv.allFinite()) return false;
    out = inv;
    return true;
  }
  if constexpr (N == 3) {
    // 3x3: positive definite by Sylvester's criterion (leading minors > 0), inverse by
    // cofactors (closed form, a few dozen operations). Not backward stable: relative error
    // ~ cond (lambda_max / lambda_mid) eps instead of Cholesky's ~ cond eps (2e-4 at cond 1e8,
    // 1e-10 at 1e4; tests/estimation/uncertainty/test_spd_inverse.cpp): ample for covariances.
    // Zero-initialised: GCC -O3 cannot see computeInverseAndDetWithCheck writes every entry.
    Eigen::Matrix<double, 3, 3> inv = Eigen::Matrix<double, 3, 3>::Zero();
    double det = 0;
    bool invertible = false;
    H.computeInverseAndDetWithCheck(inv, det, invertible, 0.0);
    const double minor2 = H(0, 0) * H(1, 1) - H(0, 1) * H(1, 0);
    if (!(H(0, 0) > 0) || !(minor2 > 0) || !(det > 0) || !invertible || !inv.allFinite())
      return false;
    out = inv;
    return true;
  }
  // Eigen's LLT reports success on NaN input (its pivot test `x <= 0` is false for NaN).
  if (!H.allFinite()) return false;
  Eigen::Matrix<double, N, N> L;
  if constexpr (N == Eigen::Dynamic) {
    const Eigen::LLT<Eigen::Matrix<double, N, N>> llt(H);
    if (llt.info() != Eigen::Success) return false;
    L = llt.matrixL();
  } else if (!cholesky_lower<N>(H, L)) {
    return false;
  }
  const int n = static_cast<int>(H.rows());  // = N when fixed: the loops keep constant bounds
  Eigen::Matrix<double, N, N> L_inv = Eigen::Matrix<double, N, N>::Zero(n, n);
  for (int j = 0; j < (N == Eigen::Dynamic ? n : N); ++j) {
    L_inv(j, j) = 1.0 / L(j, j);
    for (int i = j + 1; i < (N == Eigen::Dynamic ? n : N); ++i) {
      double s = 0;
      for (int k = j; k < i; ++k)
        s -= L(i, k) * L_inv(k, j);
      L_inv(i, j) = s / L(i, i);
    }
  }
  Eigen::Matrix<double, N, N> inv(n, n);
  inv.noalias() = L_inv.transpose() * L_inv;
  if (!inv.allFinite()) return false;  // the contract: false leaves out untouched
  out = inv;
  return true;
}

}  // namespace storetrack::uncertainty
