// The one SPD inverse (estimation/uncertainty/spd_inverse.hpp), at every size it is used with: 2x2
// (pixel covariances), 3x3 (mark covariances), 6x6 (pose normal matrices) and dynamic (joint
// calibration). Reference: matrices built as Q diag(lambda) Q^T from a random rotation Q and
// chosen eigenvalues, whose inverse Q diag(1/lambda) Q^T is known independently of any solver.
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>
#include <Eigen/QR>

#include "storetrack/uncertainty/spd_inverse.hpp"

namespace storetrack::uncertainty {
namespace {

template <int N>
using Mat = Eigen::Matrix<double, N, N>;

struct Spd {
  Eigen::MatrixXd H, inverse;  // H and its inverse from its own eigen-decomposition
  Eigen::VectorXd lambda;      // eigenvalues, ascending
};

// Eigenvalues log-uniform in [1, condition] times a scale, so that the condition number is
// exactly the one asked for (the extreme values are placed on purpose).
Spd make_spd(int n, double condition, double scale, std::mt19937_64& rng) {
  std::normal_distribution<double> g(0, 1);
  Eigen::MatrixXd A(n, n);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      A(i, j) = g(rng);
  const Eigen::MatrixXd Q = Eigen::HouseholderQR<Eigen::MatrixXd>(A).householderQ();
  std::uniform_real_distribution<double> u(0, 1);
  Eigen::VectorXd lambda(n);
  for (int i = 0; i < n; ++i)
    lambda(i) = scale * std::pow(condition, i == 0 ? 0.0 : i == n - 1 ? 1.0 : u(rng));
  Spd s;
  s.H = Q * lambda.asDiagonal() * Q.transpose();
  s.H = 0.5 * (s.H + s.H.transpose()).eval();
  s.inverse = Q * lambda.cwiseInverse().asDiagonal() * Q.transpose();
  std::sort(lambda.begin(), lambda.end());
  s.lambda = lambda;
  return s;
}

template <int N>
void expect_matches_reference(int n) {
  std::mt19937_64 rng(100 + n);
  for (double condition : {1.0, 10.0, 1e4, 1e8})
    for (double scale : {1e-10, 1.0, 1e6})  // pixel^2 .. metre^2 .. information matrices
      for (int trial = 0; trial < 20; ++trial) {
        const Spd s = make_spd(n, condition, scale, rng);
        const Mat<N> H = s.H;
        Mat<N> out = Mat<N>::Zero(n, n);
        ASSERT_TRUE(inverse_spd<N>(H, out)) << "n " << n << " condition " << condition;
        // Relative error bounds, eps the unit round-off, c = 10 (the reference itself carries
        // rounding of the same order). Cholesky (Higham, Accuracy and Stability, ch. 10/14)
        // and the 2x2 closed form: c n cond(H) eps. The 3x3 cofactor form is not backward
        // stable: each cofactor is a difference of products of entries of size lambda_max, so
        // its absolute error is ~eps lambda_max^2 against det = lambda_max lambda_mid lambda_min,
        // which gives c n cond(H) (lambda_max / lambda_mid) eps relative to |H^-1| = 1/lambda_min.
        const double lambda_max = s.lambda(n - 1), lambda_mid = s.lambda(n / 2);
        const double growth = N == 3 ? lambda_max / lambda_mid : 1.0;
        const double bound = 10.0 * n * condition * growth * std::numeric_limits<double>::epsilon();
        EXPECT_LE((out - s.inverse).norm(), bound * s.inverse.norm())
            << "n " << n << " condition " << condition << " scale " << scale;
        EXPECT_LE((out - out.transpose()).norm(), bound * out.norm());  // symmetric
      }
}

TEST(SpdInverse, MatchesTheEigenDecompositionInverseAtEverySizeInUse) {
  expect_matches_reference<2>(2);
  expect_matches_reference<3>(3);
  expect_matches_reference<6>(6);
  expect_matches_reference<Eigen::Dynamic>(9);
}

template <int N>
void expect_refused(const Mat<N>& H, const char* what) {
  const Mat<N> untouched = Mat<N>::Constant(H.rows(), H.cols(), 42.0);
  Mat<N> out = untouched;
  EXPECT_FALSE(inverse_spd<N>(H, out)) << what << " (size " << H.rows() << ")";
  EXPECT_EQ(out, untouched) << what << ": out must stay untouched";
}

template <int N>
void expect_non_spd_refused(int n) {
  std::mt19937_64 rng(200 + n);
  const Spd s = make_spd(n, 100.0, 1.0, rng);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(s.H);
  const Eigen::MatrixXd V = eig.eigenvectors();
  Eigen::VectorXd lambda = eig.eigenvalues();
  lambda(0) = -lambda(0);  // indefinite: invertible, but not a covariance
  expect_refused<N>(Mat<N>(V * lambda.asDiagonal() * V.transpose()), "indefinite");
  Mat<N> singular = s.H;  // exactly singular (positive semi-definite): a zero row and column
  singular.row(n - 1).setZero();
  singular.col(n - 1).setZero();
  expect_refused<N>(singular, "singular");
  expect_refused<N>(Mat<N>(-s.H), "negative definite");
  Mat<N> with_nan = s.H;
  with_nan(n - 1, n - 1) = std::numeric_limits<double>::quiet_NaN();
  expect_refused<N>(with_nan, "NaN entry");
  Mat<N> with_inf = s.H;
  with_inf(0, 0) = std::numeric_limits<double>::infinity();
  expect_refused<N>(with_inf, "infinite entry");
  expect_refused<N>(Mat<N>(Mat<N>::Zero(n, n)), "zero");
}

// The fixed-size factor and solve against Eigen's LLT (an independent implementation) and the
// defining identities, over conditions 1..1e10 (bounds as above, c = 10: backward error of
// L L^T c n eps, forward error of L c n sqrt(cond) eps, of the solve c n cond eps); refused
// when not positive definite.
TEST(SpdInverse, FixedSizeCholeskyAndSolveMatchEigenLlt) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g(0, 1);
  const double eps = std::numeric_limits<double>::epsilon();
  for (int trial = 0; trial < 220; ++trial) {
    const double condition = std::pow(10.0, trial % 11);
    const Mat<6> H = make_spd(6, condition, 1.0, rng).H;
    Mat<6> L;
    ASSERT_TRUE(cholesky_lower<6>(H, L));
    EXPECT_TRUE(L.isLowerTriangular(0.0));
    EXPECT_LE((L * L.transpose() - H).norm(), 60 * eps * H.norm());
    const Mat<6> L_eigen = Eigen::LLT<Mat<6>>(H).matrixL();
    EXPECT_LE((L - L_eigen).norm(), 60 * std::sqrt(condition) * eps * L_eigen.norm());
    Eigen::Matrix<double, 6, 1> b, x;
    for (int i = 0; i < 6; ++i)
      b(i) = g(rng);
    ASSERT_TRUE(solve_spd<6>(H, b, x));
    const Eigen::Matrix<double, 6, 1> x_eigen = Eigen::LLT<Mat<6>>(H).solve(b);
    EXPECT_LE((x - x_eigen).norm(), 60 * condition * eps * x_eigen.norm()) << condition;
  }
  Mat<6> indefinite = Mat<6>::Identity();
  indefinite(3, 3) = -1e-12;
  Mat<6> L;
  EXPECT_FALSE(cholesky_lower<6>(indefinite, L));
  Mat<6> nan = Mat<6>::Identity();
  nan(2, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(cholesky_lower<6>(nan, L));
  const Eigen::Matrix<double, 6, 1> untouched = Eigen::Matrix<double, 6, 1>::Constant(5);
  Eigen::Matrix<double, 6, 1> x = untouched;
  EXPECT_FALSE(solve_spd<6>(indefinite, Eigen::Matrix<double, 6, 1>::Ones(), x));
  EXPECT_EQ(x, untouched);
}

TEST(SpdInverse, RefusesWhatIsNotPositiveDefiniteAndLeavesTheOutputUntouched) {
  expect_non_spd_refused<2>(2);
  expect_non_spd_refused<3>(3);
  expect_non_spd_refused<6>(6);
  expect_non_spd_refused<Eigen::Dynamic>(9);
}

}  // namespace
}  // namespace storetrack::uncertainty
