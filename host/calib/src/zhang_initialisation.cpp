// Zhang's closed-form calibration (TPAMI 2000; MSR-TR-98-71 Appendix B for the extraction of K).
//
// Each view's homography H = [h1 h2 h3] ~ K [r1 r2 t] gives two linear constraints on the image
// of the absolute conic B = K^-T K^-1: h1^T B h2 = 0 and h1^T B h1 = h2^T B h2. The project's
// model has zero skew, and the options may tie fx to fy or fix the principal point, so B is
// written as b = P z over the free unknowns z only, and z is the unit vector minimising |V P z|
// (V: 2 rows per view), the eigenvector of the smallest eigenvalue of (V P)^T (V P). The pixels are
// first conditioned (centred, scaled by the mean image side) so that V's columns are commensurate.
#include "zhang_initialisation.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>

#include "storetrack/geometry/symmetric_eigen.hpp"

namespace storetrack::calib {
namespace {

using Mat3 = Eigen::Matrix3d;
using Vec6 = Eigen::Matrix<double, 6, 1>;

/// Zhang's v_ij: h_i^T B h_j = v_ij^T b with b = (B11, B12, B22, B13, B23, B33).
Vec6 conic_row(const Mat3& H, int i, int j) {
  const Eigen::Vector3d a = H.col(i), c = H.col(j);
  Vec6 v;
  v << a[0] * c[0], a[0] * c[1] + a[1] * c[0], a[1] * c[1], a[2] * c[0] + a[0] * c[2],
      a[2] * c[1] + a[1] * c[2], a[2] * c[2];
  return v;
}

/// Columns: the free unknowns of b under the model's zero skew (B12 = 0) and the options.
Eigen::MatrixXd conic_basis(const IntrinsicOptions& options) {
  // Unknowns in order: B11 [and B22 unless tied], B13, B23 [unless pp fixed], B33.
  std::vector<Vec6> cols;
  Vec6 b11 = Vec6::Zero();
  b11[0] = 1;
  // fx = a fy  =>  B22 / B11 = fx^2 / fy^2 = a^2 (B11 = 1/fx^2, B22 = 1/fy^2 for zero skew).
  if (options.fix_aspect_ratio) b11[2] = options.aspect_ratio * options.aspect_ratio;
  cols.push_back(b11);
  if (!options.fix_aspect_ratio) cols.push_back(Vec6::Unit(2));
  // Conditioned coordinates put the image centre at 0, so a fixed centre means B13 = B23 = 0.
  if (!options.fix_principal_point) {
    cols.push_back(Vec6::Unit(3));
    cols.push_back(Vec6::Unit(4));
  }
  cols.push_back(Vec6::Unit(5));
  Eigen::MatrixXd P(6, static_cast<Eigen::Index>(cols.size()));
  for (size_t i = 0; i < cols.size(); ++i)
    P.col(static_cast<Eigen::Index>(i)) = cols[i];
  return P;
}

std::optional<Mat3> intrinsic_matrix_from_conic(const Vec6& b_in) {
  // Zhang's Appendix B with B12 = 0 (skew 0); b is defined up to sign: take B11 > 0.
  const Vec6 b = b_in[0] < 0 ? Vec6(-b_in) : b_in;
  const double B11 = b[0], B22 = b[2], B13 = b[3], B23 = b[4], B33 = b[5];
  const double v0 = -B11 * B23 / (B11 * B22);
  const double lambda = B33 - (B13 * B13 + v0 * (-B11 * B23)) / B11;
  const double alpha2 = lambda / B11, beta2 = lambda * B11 / (B11 * B22);
  if (!(B11 > 0) || !(B22 > 0) || !(alpha2 > 0) || !(beta2 > 0)) return std::nullopt;
  const double u0 = -B13 * alpha2 / lambda;
  Mat3 K;
  K << std::sqrt(alpha2), 0, u0, 0, std::sqrt(beta2), v0, 0, 0, 1;
  return K;
}

geometry::Transform pose_from_homography(const Mat3& K_inv, const Mat3& H) {
  const Eigen::Vector3d a1 = K_inv * H.col(0), a2 = K_inv * H.col(1), a3 = K_inv * H.col(2);
  double scale = 2.0 / (a1.norm() + a2.norm());
  if ((scale * a3).z() < 0) scale = -scale;  // the board is in front of the camera
  // Nearest rotation to [a1 a2 a1 x a2] (Zhang, Appendix C). For two columns the polar factor
  // is the symmetric orthogonalisation about their bisector, so no SVD is needed.
  const Eigen::Vector3d u = (scale * a1).normalized(), v = (scale * a2).normalized();
  const Eigen::Vector3d bisector = (u + v).normalized(), split = (u - v).normalized();
  Mat3 R;
  R.col(0) = (bisector + split) / std::sqrt(2.0);
  R.col(1) = (bisector - split) / std::sqrt(2.0);
  R.col(2) = R.col(0).cross(R.col(1));
  geometry::Transform T = geometry::Transform::Identity();
  T.linear() = R;
  T.translation() = scale * a3;
  return T;
}

Mat3 similarity_normaliser(const std::vector<Eigen::Vector2d>& pts) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : pts)
    mean += p;
  mean /= static_cast<double>(pts.size());
  double spread = 0;
  for (const auto& p : pts)
    spread += (p - mean).norm();
  const double s = std::sqrt(2.0) * static_cast<double>(pts.size()) / std::max(spread, 1e-300);
  Mat3 T;
  T << s, 0, -s * mean.x(), 0, s, -s * mean.y(), 0, 0, 1;
  return T;
}

/// A centred camera with a 53 degree horizontal field of view: the start of last resort.
Mat3 nominal_camera(const ImageSize& size) {
  const double f = 0.5 * (size.width + size.height);
  Mat3 K;
  K << f, 0, 0.5 * (size.width - 1), 0, f, 0.5 * (size.height - 1), 0, 0, 1;
  return K;
}

/// K (conditioned coordinates) from the null vector of V P; nullopt if it is not a real camera.
std::optional<Mat3> closed_form_camera(const Eigen::MatrixXd& V, const IntrinsicOptions& options) {
  const Eigen::MatrixXd P = conic_basis(options);
  // Null vector of V P = eigenvector of the smallest eigenvalue of (V P)^T (V P) (at most 5 x 5;
  // the eigen solver compiles far quicker than a dynamic-size SVD).
  const Eigen::MatrixXd VP = V * P;
  const Eigen::MatrixXd normal = VP.transpose() * VP;
  return intrinsic_matrix_from_conic(P * geometry::symmetric_eigen(normal).vectors.col(0));
}

}  // namespace

Mat3 board_homography(const BoardView& view) {
  std::vector<Eigen::Vector2d> board, image;
  for (const Observation* o : view.points) {
    board.push_back(o->p_board.head<2>());
    image.push_back(o->pixel);
  }
  const Mat3 Tb = similarity_normaliser(board), Ti = similarity_normaliser(image);
  // h = eigenvector of the smallest eigenvalue of A^T A (A: the DLT rows). Squaring the
  // condition number is harmless on normalised coordinates and keeps everything 9 x 9.
  using Row = Eigen::Matrix<double, 1, 9>;
  Eigen::Matrix<double, 9, 9> AtA = Eigen::Matrix<double, 9, 9>::Zero();
  for (size_t k = 0; k < board.size(); ++k) {
    const Eigen::Vector3d X = Tb * board[k].homogeneous();
    const Eigen::Vector3d x = Ti * image[k].homogeneous();
    Row a, b;
    a << X.transpose(), 0, 0, 0, -x.x() * X.transpose();
    b << 0, 0, 0, X.transpose(), -x.y() * X.transpose();
    AtA.noalias() += a.transpose() * a + b.transpose() * b;
  }
  const Eigen::Matrix<double, 9, 1> h = geometry::symmetric_eigen(AtA).vectors.col(0);
  Mat3 Hn;
  Hn << h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8];
  const Mat3 H = Ti.inverse() * Hn * Tb;
  return H / H(2, 2);
}

ZhangStart zhang_initialisation(const std::vector<BoardView>& views, const ImageSize& size,
                                const IntrinsicOptions& options) {
  // Conditioning N: image centre at 0, mean side 1.
  const double side = 0.5 * (size.width + size.height);
  const double cx0 = 0.5 * (size.width - 1), cy0 = 0.5 * (size.height - 1);
  Mat3 N;
  N << 1 / side, 0, -cx0 / side, 0, 1 / side, -cy0 / side, 0, 0, 1;

  std::vector<Mat3> homographies;
  Eigen::MatrixXd V(2 * static_cast<Eigen::Index>(views.size()), 6);
  for (size_t i = 0; i < views.size(); ++i) {
    homographies.push_back(views[i].homography ? *views[i].homography : board_homography(views[i]));
    Mat3 Hc = N * homographies.back();
    Hc /= Hc.norm();
    const auto r = static_cast<Eigen::Index>(2 * i);
    V.row(r) = conic_row(Hc, 0, 1).transpose();
    V.row(r + 1) = (conic_row(Hc, 0, 0) - conic_row(Hc, 1, 1)).transpose();
  }

  // Strong distortion or weak tilt can leave the general solution without a real focal length;
  // then the principal point at the centre and fx = a fy (one unknown, like OpenCV's
  // initCameraMatrix2D), then a nominal camera. LM starts from there; degenerate views are
  // refused after it (intrinsic_calibration.cpp, check_board_orientations).
  ZhangStart out;
  IntrinsicOptions centred = options;
  centred.fix_principal_point = true;
  centred.fix_aspect_ratio = true;
  if (!options.fix_aspect_ratio) centred.aspect_ratio = 1;
  Mat3 K = nominal_camera(size);
  out.method = "nominal camera (closed forms failed)";
  if (const auto general = closed_form_camera(V, options)) {
    K = N.inverse() * *general;
    out.method = "Zhang closed form";
  } else if (const auto simple = closed_form_camera(V, centred)) {
    K = N.inverse() * *simple;
    out.method = "Zhang closed form, centred principal point";
  }

  camera::Intrinsics& in = out.intrinsics;
  in.width = size.width;
  in.height = size.height;
  in.fx = K(0, 0);
  in.fy = K(1, 1);
  in.cx = options.fix_principal_point ? cx0 : K(0, 2);
  in.cy = options.fix_principal_point ? cy0 : K(1, 2);
  if (options.fix_aspect_ratio) in.fx = options.aspect_ratio * in.fy;
  Mat3 K_model;
  K_model << in.fx, 0, in.cx, 0, in.fy, in.cy, 0, 0, 1;
  const Mat3 K_inv = K_model.inverse();
  for (const Mat3& H : homographies)
    out.T_c_b.push_back(pose_from_homography(K_inv, H));
  return out;
}

}  // namespace storetrack::calib
